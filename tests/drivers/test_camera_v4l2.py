"""V4L2Camera beyond the contract: settings read back, stale-frame rejection, the frame clock, raw mono decoding.

No camera here: V4L2Camera is handed real cv2.VideoCapture objects on files written in tmp_path (never a mock), and
the parts that only a V4L2 device exercises (raw Y16 buffers, kernel timestamps) are pure functions tested on
constructed inputs. The contract suite is test_camera_contract.py.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.errors import ConfigError, DeviceError, DeviceTimeout
from drivers.v4l2 import (
    SELECT_TIMEOUT_ENV,
    CameraSettings,
    FrameClock,
    V4L2Camera,
    decode_raw,
    fourcc_code,
    fourcc_text,
    open_v4l2_capture,
)

W, H = 32, 24


def _sequence(folder: Path, count: int, dtype=np.uint8) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(count):
        img = np.full((H, W), i * (1000 if dtype == np.uint16 else 10), dtype)
        assert cv2.imwrite(str(folder / f"{i:06d}.png"), img)
    return folder / "%06d.png"


def _images(tmp_path: Path, count: int = 8, dtype=np.uint8) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(str(_sequence(tmp_path / "seq", count, dtype)), cv2.CAP_IMAGES)
    assert cap.isOpened()
    return cap


def _ffv1(tmp_path: Path, count: int, fps: float) -> Path:
    path = tmp_path / "frames.mkv"
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"FFV1"), fps, (W, H), False)  # (W, H)
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write FFV1 through FFMPEG")
    for i in range(count):
        writer.write(np.full((H, W), i * 20, np.uint8))
    writer.release()
    return path


# ----- stale frames and the frame clock -------------------------------------------------------------------------


def test_frames_stamped_before_after_s_are_dropped(tmp_path):
    # A 10 fps video: frame k carries device time k * 100 ms (CAP_PROP_POS_MSEC). The injected clock runs on the
    # same time base (as CLOCK_MONOTONIC does for V4L2 buffers), so the camera must skip frames 0..3 as stale.
    video = _ffv1(tmp_path, count=8, fps=10.0)
    base = time.monotonic()
    cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    cam = V4L2Camera(cap, CameraSettings.keep(convert_rgb=False), clock=lambda: time.monotonic() - base)
    with cam:
        frame = cam.grab(after_s=0.35, timeout_s=2.0)
        assert frame.timestamp_s == pytest.approx(0.4)
        assert int(frame.image[0, 0]) == 4 * 20  # frame 4: the first one stamped after 0.35 s
        assert frame.meta["stale_dropped"] == 4
        assert frame.meta["clock"] == "device"
        nxt = cam.grab(after_s=frame.timestamp_s, timeout_s=2.0)
        assert int(nxt.image[0, 0]) == 5 * 20 and nxt.meta["stale_dropped"] == 0


def test_frame_clock_device_mode_uses_kernel_time_and_rejects_repeats():
    fc = FrameClock(has_device_time=True)
    assert fc.stamp(1000_000.0, host_s=1000.004) == pytest.approx(1000.0)  # within a second: same clock
    assert fc.mode == "device"
    assert fc.stamp(1000_033.0, host_s=1000.040) == pytest.approx(1000.033)
    # The same buffer handed back after a select() timeout: its time did not advance.
    assert fc.stamp(1000_033.0, host_s=1001.040) is None
    assert fc.stamp(1000_020.0, host_s=1001.050) is None
    assert fc.stamp(1000_066.0, host_s=1001.060) == pytest.approx(1000.066)


def test_frame_clock_offset_mode_maps_another_clock_by_the_least_delayed_frame():
    fc = FrameClock(has_device_time=True)
    # Device clock 5000 s behind the host, frames delayed 30, 10, 20 ms on their way to the host.
    t1 = fc.stamp(0.0, host_s=5000.030)
    assert fc.mode == "offset" and t1 == pytest.approx(5000.030)
    t2 = fc.stamp(100.0, host_s=5000.110)
    assert t2 == pytest.approx(5000.110)  # the least delayed so far: offset 5000.010
    t3 = fc.stamp(200.0, host_s=5000.220)
    assert t3 == pytest.approx(5000.210)  # 200 ms after frame 0 on the device clock + the best offset
    assert t1 < t2 < t3


def test_frame_clock_host_mode_when_the_backend_has_no_frame_times():
    fc = FrameClock(has_device_time=False)
    assert fc.mode == "host"
    assert fc.stamp(-1.0, host_s=12.5) == 12.5


def test_image_sequence_uses_host_time_and_discards_after_open(tmp_path):
    cam = V4L2Camera(_images(tmp_path, 8), CameraSettings.keep(discard=3))
    with cam:
        t0 = time.monotonic()
        frame = cam.grab(after_s=t0, timeout_s=1.0)
        assert int(frame.image[0, 0]) == 30  # frames 0, 1, 2 were discarded
        assert t0 < frame.timestamp_s <= time.monotonic()
        assert cam.describe()["frame_clock"] == "host" and cam.describe()["discarded"] == 3


def test_a_stream_that_stops_times_out_naming_the_failed_reads(tmp_path):
    cam = V4L2Camera(_images(tmp_path, 2), CameraSettings.keep())
    with cam:
        cam.grab(after_s=0.0, timeout_s=1.0)
        cam.grab(after_s=0.0, timeout_s=1.0)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"read\(s\) failed"):
            cam.grab(after_s=0.0, timeout_s=0.1)
        assert time.monotonic() - t0 < 0.5


def test_discard_more_frames_than_the_stream_has_times_out(tmp_path):
    with pytest.raises(DeviceTimeout, match="only 2 of the 5 frames to discard"):
        V4L2Camera(_images(tmp_path, 2), CameraSettings.keep(discard=5, timeout_ms=20))


# ----- settings the backend cannot apply ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("override", "pattern"),
    [
        ({"fourcc": "GREY"}, r"fourcc is unknown, wanted 'GREY'"),
        ({"width": 640}, r"width/height is 32x24, wanted 640x24"),
        ({"height": 480}, r"width/height is 32x24, wanted 32x480"),
        ({"fps": 30.0}, r"fps is -?\d+, wanted 30"),
        ({"exposure_ms": 16.7}, r"exposure is unavailable, wanted 16.7 ms \(167 × 100 µs\)"),
        ({"buffer_size": 1}, r"buffer_size is -1.0, wanted 1"),
        ({"convert_rgb": False}, r"convert_rgb is -1.0, wanted off"),
    ],
)
def test_a_setting_the_backend_cannot_apply_is_a_clear_error(tmp_path, override, pattern):
    cap = _images(tmp_path)
    with pytest.raises(DeviceError, match=pattern) as err:
        V4L2Camera(cap, CameraSettings.keep(**override), name="seq")
    assert "camera seq" in str(err.value) and "CV_IMAGES backend cannot change it" in str(err.value)
    assert not cap.isOpened()  # released on the failure path, not leaked


def test_defaults_refuse_a_file_capture_instead_of_silently_keeping_buffers(tmp_path):
    with pytest.raises(DeviceError, match="buffer_size"):
        V4L2Camera(_images(tmp_path), CameraSettings())


def test_a_closed_capture_is_refused(tmp_path):
    cap = _images(tmp_path)
    cap.release()
    with pytest.raises(DeviceError, match="not open"):
        V4L2Camera(cap, CameraSettings.keep(), name="x")


def test_16_bit_frames_stay_16_bit(tmp_path):
    with V4L2Camera(_images(tmp_path, 4, np.uint16), CameraSettings.keep()) as cam:
        frames = [cam.grab(after_s=0.0, timeout_s=1.0) for _ in range(4)]
    assert [int(f.image[5, 5]) for f in frames] == [0, 1000, 2000, 3000]
    assert all(f.image.dtype == np.uint16 and f.image.shape == (H, W) for f in frames)
    assert [f.sequence for f in frames] == [1, 2, 3, 4]


# ----- settings ---------------------------------------------------------------------------------------------------


def test_settings_normalise_fourcc_and_keep():
    assert CameraSettings(fourcc="y16").fourcc == "Y16 "
    assert CameraSettings(fourcc="keep").fourcc is None
    assert CameraSettings().fourcc is None
    for bad in ({"fourcc": "TOOLONG"}, {"width": 0}, {"fps": -1.0}, {"exposure_ms": 0.0}, {"discard": -1},
                {"buffer_size": 0}, {"timeout_ms": 0.0}):
        with pytest.raises(ConfigError):
            CameraSettings(**bad)


def test_settings_from_the_rig_configuration():
    from rig.config import CameraConfig

    cfg = CameraConfig(width=1280, height=720, fps=30.0, fourcc="Y16 ", exposure_ms=16.667, settle_ms=25.0,
                       timeout_ms=1500.0, discard=4)
    s = CameraSettings.from_config(cfg)
    assert (s.width, s.height, s.fps, s.fourcc, s.exposure_ms) == (1280, 720, 30.0, "Y16 ", 16.667)
    assert (s.settle_ms, s.timeout_ms, s.discard, s.buffer_size) == (25.0, 1500.0, 4, 1)


def test_fourcc_codes_round_trip():
    assert fourcc_text(fourcc_code("MJPG")) == "MJPG"
    assert fourcc_text(fourcc_code("Y16")) == "Y16 "
    assert fourcc_text(-1) == "" and fourcc_text(0) == ""


# ----- raw mono buffers (what CAP_V4L2 returns with CONVERT_RGB off) ------------------------------------------


def test_decode_grey_with_padded_rows():
    image = np.arange(H * W, dtype=np.uint32).reshape(H, W).astype(np.uint8)
    stride = W + 8  # bytesperline larger than the width, as some drivers report
    padded = np.zeros((H, stride), np.uint8)
    padded[:, :W] = image
    out = decode_raw(padded.reshape(1, -1), fourcc="GREY", width=W, height=H)
    assert out.dtype == np.uint8 and np.array_equal(out, image)


def test_decode_y16_little_endian_keeps_all_16_bits():
    image = (np.arange(H * W).reshape(H, W) * 83 % 65536).astype(np.uint16)
    raw = np.frombuffer(image.astype("<u2").tobytes(), np.uint8).reshape(1, -1)
    out = decode_raw(raw, fourcc="Y16", width=W, height=H)
    assert out.dtype == np.uint16 and np.array_equal(out, image) and int(out.max()) > 255


def test_decode_y10_is_not_rescaled():
    image = (np.arange(H * W).reshape(H, W) * 5 % 1024).astype(np.uint16)
    image[0, 0] = 1023
    raw = np.frombuffer(image.astype("<u2").tobytes(), np.uint8)
    out = decode_raw(raw, fourcc="Y10 ", width=W, height=H)
    assert np.array_equal(out, image) and int(out.max()) == 1023


def test_decode_refuses_short_buffers_and_unknown_formats():
    with pytest.raises(DeviceError, match="short Y16 frame"):
        decode_raw(np.zeros((1, W * H), np.uint8), fourcc="Y16", width=W, height=H)
    with pytest.raises(DeviceError, match="cannot decode raw 'YUYV'"):
        decode_raw(np.zeros((1, 2 * W * H), np.uint8), fourcc="YUYV", width=W, height=H)


def test_decode_passes_an_already_shaped_frame_through():
    image = np.ones((H, W), np.uint16)
    assert decode_raw(image, fourcc="Y16", width=W, height=H) is image


# ----- opening devices --------------------------------------------------------------------------------------------


def test_open_a_missing_device_names_it_and_the_fix(monkeypatch):
    monkeypatch.delenv(SELECT_TIMEOUT_ENV, raising=False)
    with pytest.raises(DeviceError, match=r"/dev/v4l/by-id/no-such-camera: no such device .*rig devices"):
        open_v4l2_capture("/dev/v4l/by-id/no-such-camera")
    assert os.environ[SELECT_TIMEOUT_ENV] == "1"  # set before any open, so OpenCV never waits its default 10 s


def test_open_respects_a_select_timeout_the_user_set(monkeypatch):
    monkeypatch.setenv(SELECT_TIMEOUT_ENV, "3")
    with pytest.raises(DeviceError):
        open_v4l2_capture("/dev/v4l/by-id/no-such-camera")
    assert os.environ[SELECT_TIMEOUT_ENV] == "3"


def test_open_something_that_is_not_a_camera(tmp_path, monkeypatch):
    monkeypatch.setenv(SELECT_TIMEOUT_ENV, "1")
    not_a_camera = tmp_path / "video0"
    not_a_camera.write_bytes(b"\0" * 16)
    with pytest.raises(DeviceError, match="cannot open it .*video-index0"):
        open_v4l2_capture(str(not_a_camera))


def test_open_without_permission(tmp_path, monkeypatch):
    if os.geteuid() == 0:
        pytest.skip("root can open anything")
    monkeypatch.setenv(SELECT_TIMEOUT_ENV, "1")
    locked = tmp_path / "video9"
    locked.write_bytes(b"")
    locked.chmod(0)
    with pytest.raises(DeviceError, match="permission denied .*video group"):
        open_v4l2_capture(str(locked))
