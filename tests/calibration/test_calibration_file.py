"""The calibration file: good files load, each kind of bad file gives one clear error naming the key."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibration.errors import CalibrationFileError
from calibration.file import (
    CalibrationFile,
    dumps_calibration,
    load_calibration,
    parse_calibration,
    save_calibration,
)
from calibration.models import Intrinsics, ProCam, look_at


def _procam() -> ProCam:
    cam = Intrinsics(1280, 1024, [[2300, 0, 640.2], [0, 2301, 511.7], [0, 0, 1]], [-0.05, 0.02, 0.001, -0.0005, 0.0])
    proj = Intrinsics(1024, 1024, [[1800, 0, 511.5], [0, 1800, 900.0], [0, 0, 1]], [0.01, 0, 0, 0, 0])
    R = look_at(np.array([300.0, 0, 0]), np.array([0, 0, 900.0]))
    return ProCam(cam, proj, R, [300.0, 0.0, 0.0])


def _good() -> dict:
    return json.loads(dumps_calibration(CalibrationFile.from_procam(_procam(), quality={"stereo_rms_px": 0.2})))


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "calibration.json"
    save_calibration(CalibrationFile.from_procam(_procam(), provenance={"by": "test"}), path)
    back = load_calibration(path).to_procam()
    ref = _procam()
    np.testing.assert_array_equal(back.camera.K, ref.camera.K)
    np.testing.assert_array_equal(back.camera.dist, ref.camera.dist)
    np.testing.assert_array_equal(back.R_proj_cam, ref.R_proj_cam)
    np.testing.assert_array_equal(back.t_proj_cam, ref.t_proj_cam)
    assert load_calibration(path).provenance == {"by": "test"}
    assert not list(tmp_path.glob(".*tmp")), "no temporary file left behind"


def test_camera_only_file_loads_but_has_no_procam():
    data = _good()
    for k in ("projector", "R", "t"):
        del data[k]
    cal = parse_calibration(data)
    assert not cal.has_projector
    with pytest.raises(CalibrationFileError, match="only the camera part.*rig calibrate"):
        cal.to_procam()


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("camera"), r"camera: missing"),
        (lambda d: d["camera"].pop("K"), r"camera\.K: missing"),
        (lambda d: d.__setitem__("colour", 1), r"colour: unknown key"),
        (lambda d: d["projector"].__setitem__("skew", 0), r"projector\.skew: unknown key"),
        (lambda d: d["camera"].__setitem__("K", [[1, 0, 0], [0, 1, 0]]), r"camera\.K: expected a 3x3 matrix, got 2 rows"),
        (lambda d: d["camera"].__setitem__("K", [[1, 0, 0], [0, 1, 0], [0, 0, 2]]), r"camera\.K: expected \[\[fx"),
        (lambda d: d["camera"].__setitem__("dist", [0.1, 0.2, 0.3]), r"camera\.dist: expected 4, 5, 8, 12 or 14"),
        (lambda d: d["camera"].__setitem__("width", -5), r"camera\.width: must be a positive"),
        (lambda d: d.__setitem__("R", [[1, 0, 0], [0, 1, 0], [0, 0, 2]]), r"R: expected a rotation matrix"),
        (lambda d: d.__setitem__("R", [[1, 0, 0], [0, 1, 0], [0, 0, -1]]), r"R: expected a rotation matrix"),
        (lambda d: d.__setitem__("t", [1, 2]), r"t: expected \[tx, ty, tz\]"),
        (lambda d: d.pop("t"), r"has projector, R but not t"),
        (lambda d: d.__setitem__("format_version", 2), r"format_version: this version of rig reads format_version 1, got 2"),
    ],
)
def test_bad_files_name_the_key(tmp_path, mutate, message):
    data = _good()
    mutate(data)
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationFileError, match=message) as info:
        load_calibration(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(CalibrationFileError, match="no such calibration file.*rig calibrate"):
        load_calibration(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"format_version": 1,,}')
    with pytest.raises(CalibrationFileError, match=r"not valid JSON \(line 1"):
        load_calibration(bad)
    arr = tmp_path / "arr.json"
    arr.write_text("[1, 2]")
    with pytest.raises(CalibrationFileError, match="expected a JSON object"):
        load_calibration(arr)


def test_file_is_human_readable():
    text = dumps_calibration(CalibrationFile.from_procam(_procam()))
    assert '"K": [\n      [2300.0, 0.0, 640.2],' in text
    assert text.count("\n") < 60
