"""The camera contract on a real V4L2 camera: opt-in, skipped unless RIG_TEST_CAMERA names a device.

    RIG_TEST_CAMERA=/dev/v4l/by-id/usb-…-video-index0 .venv/bin/pytest -m hardware tests/drivers/test_camera_hardware.py

Optional: RIG_TEST_CAMERA_FOURCC (e.g. GREY, Y16, YUYV; default: keep the camera's format),
RIG_TEST_CAMERA_EXPOSURE_MS (default: keep the camera's exposure control), RIG_TEST_CAMERA_FPS.
The contract tests themselves are test_camera_contract.py's, imported here and run on this module's fixture.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest

DEVICE = os.environ.get("RIG_TEST_CAMERA", "")

pytestmark = [
    pytest.mark.hardware,
    pytest.mark.skipif(not DEVICE, reason="set RIG_TEST_CAMERA to a V4L2 device to run the camera hardware tests"),
]

_spec = importlib.util.spec_from_file_location("_camera_contract", Path(__file__).with_name("test_camera_contract.py"))
assert _spec is not None and _spec.loader is not None
_contract = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = _contract  # dataclasses look their module up while the file executes
_spec.loader.exec_module(_contract)

# The contract, run on the hardware `camera_case` below (pytest collects these names in this module).
for _name in dir(_contract):
    if _name.startswith("test_"):
        globals()[_name] = getattr(_contract, _name)


def _settings():
    from drivers.v4l2 import CameraSettings

    fps = os.environ.get("RIG_TEST_CAMERA_FPS")
    exposure = os.environ.get("RIG_TEST_CAMERA_EXPOSURE_MS")
    return CameraSettings(
        fourcc=os.environ.get("RIG_TEST_CAMERA_FOURCC"),
        fps=float(fps) if fps else None,
        exposure_ms=float(exposure) if exposure else None,
        discard=3,
        timeout_ms=3000.0,
    )


def _open():
    from drivers.v4l2 import V4L2Camera, open_v4l2_capture

    return V4L2Camera(open_v4l2_capture(DEVICE), _settings(), name=DEVICE)


@pytest.fixture
def camera_case():
    cam = _open()
    info = cam.describe()
    dtype = None
    if info.get("bit_depth"):
        dtype = np.dtype(np.uint16 if info["bit_depth"] > 8 else np.uint8)
    case = _contract.CameraCase(cam, cam.width, cam.height, dtype)
    yield case
    cam.close()


def test_settings_are_read_back_and_recorded():
    with _open() as cam:
        info = cam.describe()
        s = cam.settings
        if s.fourcc is not None:
            assert info["fourcc"] == s.fourcc.strip()
        if s.exposure_ms is not None:
            assert abs(info["exposure_ms"] - s.exposure_ms) <= 0.1  # one 100 µs step
            assert info["auto_exposure"] in ("manual", "absent")
        assert info["buffer_size"] == 1 and info["backend"] == "V4L2"
        assert info["frame_clock"] == "device"  # kernel buffer times on CLOCK_MONOTONIC


def test_a_frame_queued_before_a_pause_is_not_returned():
    # Frames keep arriving while the host is busy; after a pause the one waiting in the buffer is stale.
    with _open() as cam:
        cam.grab(after_s=time.monotonic(), timeout_s=3.0)
        time.sleep(0.5)
        switch = time.monotonic()
        frame = cam.grab(after_s=switch, timeout_s=3.0)
        assert frame.timestamp_s > switch
        assert frame.timestamp_s - switch < 1.0


def test_mono_formats_keep_full_bit_depth():
    from drivers.v4l2 import MONO_FORMATS

    fourcc = _settings().fourcc
    if fourcc not in MONO_FORMATS:
        pytest.skip("set RIG_TEST_CAMERA_FOURCC to a mono format (GREY, Y10, Y12, Y16) to check bit depth")
    with _open() as cam:
        image = cam.grab(after_s=time.monotonic(), timeout_s=3.0).image
    assert image.ndim == 2 and image.shape == (cam.height, cam.width)
    assert image.dtype == (np.uint8 if MONO_FORMATS[fourcc][0] == 1 else np.uint16)
