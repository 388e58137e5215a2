"""The camera contract (drivers.base.Camera), run against every implementation.

Implementations: V4L2Camera handed a real cv2.VideoCapture on files written here (an 8-bit and a 16-bit PNG
sequence through CAP_IMAGES, a lossless FFV1 video through CAP_FFMPEG), ReplayCamera on a capture directory, and
SimCamera once drivers.sim exists. tests/drivers/test_camera_hardware.py runs these same tests on a real camera.

Every implementation is reached through the `camera_case` fixture; a module that defines its own `camera_case`
and imports these test functions runs the contract on its cameras.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.errors import DeviceError, DeviceTimeout
from drivers.base import Camera

WIDTH, HEIGHT, COUNT = 64, 48, 40


@dataclass
class CameraCase:
    """A camera under test and what it must deliver. frames: the exact images it may return (None: unknown)."""

    camera: Camera
    width: int | None
    height: int | None
    dtype: np.dtype | None
    frames: list[np.ndarray] | None = None


def make_frames(dtype, *, count: int = COUNT, channels: int = 1) -> list[np.ndarray]:
    """Distinct frames: a gradient plus the frame number, using the full range of 16-bit (values far above 255)."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    out = []
    for i in range(count):
        if dtype == np.uint16:
            img = (xx * 900 + yy * 50 + i * 37).astype(np.uint16)
        else:
            img = ((xx * 3 + yy + i * 5) % 256).astype(np.uint8)
        img[0, 0] = i  # the frame number, readable after lossless round trips
        if channels == 3:
            img = np.dstack([img, np.roll(img, 1, axis=1), rng.integers(0, 255, img.shape).astype(img.dtype)])
        out.append(img)
    return out


def write_sequence(folder: Path, frames: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        assert cv2.imwrite(str(folder / f"{i:06d}.png"), f)
    return folder


def write_ffv1(path: Path, frames: list[np.ndarray], fps: float = 10.0) -> Path | None:
    """A lossless grey FFV1 video, or None when this OpenCV build cannot write one."""
    if "FFMPEG" not in [cv2.videoio_registry.getBackendName(b) for b in cv2.videoio_registry.getWriterBackends()]:
        return None
    size = (WIDTH, HEIGHT)  # OpenCV takes (W, H)
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"FFV1"), fps, size, False)
    if not writer.isOpened():
        return None
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def write_capture_dir(folder: Path, frames: list[np.ndarray]) -> Path:
    """A capture directory as `rig scan --record` lays it out (manifest.json + frames/NNNNNN.png)."""
    write_sequence(folder / "frames", frames)
    entries = [{"file": f"frames/{i:06d}.png", "pattern": 0, "timestamp_s": 100.0 + 0.1 * i} for i in range(len(frames))]
    (folder / "manifest.json").write_text(json.dumps({"format": "rig-capture", "complete": True, "frames": entries}))
    return folder


def _v4l2_on(capture: cv2.VideoCapture, **settings):
    from drivers.v4l2 import CameraSettings, V4L2Camera

    assert capture.isOpened()
    return V4L2Camera(capture, CameraSettings.keep(**settings), name="file-backed")


def _sim_case(bit_depth: int) -> CameraCase:
    sim = pytest.importorskip("drivers.sim", reason="drivers.sim (the simulator) is not in this tree yet")
    if not all(hasattr(sim, n) for n in ("SimWorld", "SimProjector", "SimCamera", "preset")):
        pytest.skip("drivers.sim does not export SimWorld, SimProjector, SimCamera, preset yet")
    from calibration.models import Intrinsics, ProCam
    from drivers.sim.presets import tabletop_procam
    from drivers.sim.render import RenderOptions

    def shrunk(i: Intrinsics, s: int) -> Intrinsics:
        # The tabletop rig at 1/s of its resolution (pixel centres kept: c' = (c + 0.5) / s - 0.5), so the
        # one-off ray cast takes milliseconds instead of half a minute.
        K = np.array(i.K, dtype=np.float64)
        K[0, 0] /= s
        K[1, 1] /= s
        K[0, 2] = (K[0, 2] + 0.5) / s - 0.5
        K[1, 2] = (K[1, 2] + 0.5) / s - 0.5
        return Intrinsics(i.width // s, i.height // s, K, i.dist)

    truth = tabletop_procam()
    small = ProCam(shrunk(truth.camera, 8), shrunk(truth.projector, 8), truth.R_proj_cam, truth.t_proj_cam)
    world = sim.SimWorld(sim.preset("tabletop", truth=small), options=RenderOptions(supersample=1, bit_depth=bit_depth))
    projector = sim.SimProjector(world)
    camera = sim.SimCamera(world, source=projector)
    dtype = np.dtype(np.uint16 if bit_depth == 16 else np.uint8)
    return CameraCase(camera, small.camera.width, small.camera.height, dtype)


CASES = ["v4l2-images-u8", "v4l2-images-u16", "v4l2-ffmpeg-ffv1", "replay-u16", "sim-u8", "sim-u16"]


def build_case(kind: str, tmp_path: Path) -> CameraCase:
    if kind == "v4l2-images-u8":
        frames = make_frames(np.uint8)
        folder = write_sequence(tmp_path / "seq8", frames)
        cam = _v4l2_on(cv2.VideoCapture(str(folder / "%06d.png"), cv2.CAP_IMAGES), discard=2)
        return CameraCase(cam, WIDTH, HEIGHT, np.dtype(np.uint8), frames)
    if kind == "v4l2-images-u16":
        frames = make_frames(np.uint16)
        folder = write_sequence(tmp_path / "seq16", frames)
        cam = _v4l2_on(cv2.VideoCapture(str(folder / "%06d.png"), cv2.CAP_IMAGES))
        return CameraCase(cam, WIDTH, HEIGHT, np.dtype(np.uint16), frames)
    if kind == "v4l2-ffmpeg-ffv1":
        frames = make_frames(np.uint8)
        video = write_ffv1(tmp_path / "grey.mkv", frames)
        if video is None:
            pytest.skip("this OpenCV build has no FFMPEG writer for FFV1")
        # CONVERT_RGB off: FFMPEG then delivers the grey frames as (H, W), exactly as written.
        cam = _v4l2_on(cv2.VideoCapture(str(video), cv2.CAP_FFMPEG), discard=1, convert_rgb=False)
        return CameraCase(cam, WIDTH, HEIGHT, np.dtype(np.uint8), frames)
    if kind == "replay-u16":
        from drivers.replay import ReplayCamera

        frames = make_frames(np.uint16)
        cam = ReplayCamera(write_capture_dir(tmp_path / "capture", frames))
        return CameraCase(cam, WIDTH, HEIGHT, np.dtype(np.uint16), frames)
    if kind.startswith("sim-"):
        return _sim_case(16 if kind == "sim-u16" else 8)
    raise AssertionError(kind)


@pytest.fixture(params=CASES)
def camera_case(request, tmp_path):
    case = build_case(request.param, tmp_path)
    yield case
    case.camera.close()


def _grab_now(cam: Camera, timeout_s: float = 2.0):
    return cam.grab(after_s=time.monotonic(), timeout_s=timeout_s)


def test_implements_the_camera_protocol(camera_case):
    assert isinstance(camera_case.camera, Camera)


def test_frame_size_matches_width_and_height(camera_case):
    cam = camera_case.camera
    frame = _grab_now(cam)
    assert frame.image.shape[:2] == (cam.height, cam.width)
    if camera_case.width is not None:
        assert (cam.width, cam.height) == (camera_case.width, camera_case.height)


def test_pixels_and_bit_depth_are_preserved(camera_case):
    frame = _grab_now(camera_case.camera)
    image = frame.image
    assert image.dtype in (np.uint8, np.uint16)
    assert image.ndim in (2, 3)
    if camera_case.dtype is not None:
        assert image.dtype == camera_case.dtype
    if camera_case.frames is not None:
        # Exactly one of the frames written, bit for bit (no 16 -> 8 bit squash, no grey -> BGR conversion).
        assert any(np.array_equal(image, f) for f in camera_case.frames)
        if image.dtype == np.uint16:
            assert int(image.max()) > 255


def test_grab_returns_only_frames_after_after_s(camera_case):
    cam = camera_case.camera
    first = _grab_now(cam)
    after = time.monotonic() + 0.08
    frame = cam.grab(after_s=after, timeout_s=2.0)
    assert frame.timestamp_s > after
    assert time.monotonic() > after  # it did not hand over a frame before the switch + settle time had passed
    assert frame.timestamp_s > first.timestamp_s
    assert frame.sequence > first.sequence
    nxt = cam.grab(after_s=frame.timestamp_s, timeout_s=2.0)
    assert nxt.timestamp_s > frame.timestamp_s
    if camera_case.frames is not None:
        assert not np.array_equal(nxt.image, frame.image)  # a new frame, not the same buffer again


def test_deadline_raises_device_timeout_quickly(camera_case):
    cam = camera_case.camera
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout):
        cam.grab(after_s=t0 + 30.0, timeout_s=0.15)
    # It may give up at once when no frame can arrive in time, or at the deadline; never much later.
    assert time.monotonic() - t0 < 1.0
    # The camera is still usable after a timeout.
    assert _grab_now(cam).image.shape[:2] == (cam.height, cam.width)


def test_close_is_idempotent_and_final(camera_case):
    cam = camera_case.camera
    _grab_now(cam)
    cam.close()
    cam.close()
    with pytest.raises(DeviceError):
        _grab_now(cam)


def test_context_manager_closes(camera_case):
    cam = camera_case.camera
    with cam as entered:
        assert entered is cam
        _grab_now(cam)
    with pytest.raises(DeviceError):
        _grab_now(cam)


def test_describe_is_a_json_manifest_entry(camera_case):
    cam = camera_case.camera
    info = cam.describe()
    assert isinstance(info, dict) and info
    assert json.loads(json.dumps(info)) == info
    if "width" in info:
        assert (info["width"], info["height"]) == (cam.width, cam.height)
