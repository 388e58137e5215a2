"""Raw capture directories: frames on disk at full depth with a streamed manifest that survives a crash."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from calibration.errors import DeviceError
from rig.capture import CaptureWriter


def test_frames_and_manifest(tmp_path):
    d = tmp_path / "cap"
    with CaptureWriter(d, header={"config": "x"}) as w:
        w.write_pattern(0, np.zeros((8, 8), np.uint8))
        for i in range(3):
            w.write_frame(np.full((4, 5), 1000 * i, np.uint16), pattern=0, timestamp_s=float(i), exposure_ms=16.0)
        # Mid-scan: manifest says incomplete, frames.jsonl already lists every frame on disk.
        assert json.loads((d / "manifest.json").read_text())["complete"] is False
        assert len((d / "frames.jsonl").read_text().splitlines()) == 3
    m = json.loads((d / "manifest.json").read_text())
    assert m["complete"] is True and m["format"] == "rig-capture" and m["software"]["rig"]
    assert [f["file"] for f in m["frames"]] == [f"frames/{i:06d}.png" for i in range(3)]
    assert m["frames"][2]["exposure_ms"] == 16.0
    back = cv2.imread(str(d / "frames/000002.png"), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and back[0, 0] == 2000


def test_error_marks_incomplete_and_keeps_frames(tmp_path):
    d = tmp_path / "cap"
    with pytest.raises(DeviceError):
        with CaptureWriter(d, header={}) as w:
            w.write_frame(np.zeros((4, 4), np.uint8), pattern=0, timestamp_s=0.0)
            raise DeviceError("camera unplugged")
    m = json.loads((d / "manifest.json").read_text())
    assert m["complete"] is False and len(m["frames"]) == 1 and (d / "frames/000000.png").exists()


def test_refuses_to_overwrite(tmp_path):
    d = tmp_path / "cap"
    CaptureWriter(d, header={}).close()
    with pytest.raises(DeviceError, match="already holds a capture"):
        CaptureWriter(d, header={})
