"""The simulated projector and camera: the drivers.base contracts, and the camera seeing what the projector shows."""

from __future__ import annotations

import time

import numpy as np
import pytest

from calibration.errors import DeviceError, DeviceTimeout
from calibration.models import Intrinsics, ProCam, look_at
from drivers.base import Camera, Projector
from drivers.sim import Plane, RenderOptions, Scene, SimCamera, SimProjector, SimRig, SimWorld


@pytest.fixture(scope="module")
def world() -> SimWorld:
    cam = Intrinsics(64, 48, np.array([[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]]))
    proj = Intrinsics(32, 32, np.array([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]]))
    t = np.array([50.0, 0.0, 0.0])
    procam = ProCam(cam, proj, look_at(t, np.array([0, 0, 400.0])), t)
    rig = SimRig("test", procam, Scene(objects=[Plane((0, 0, 400), (0, 0, -1))]), (300.0, 500.0), "a plane")
    return SimWorld(rig, options=RenderOptions(noise_grey=0.0, supersample=1, ambient=0.1), seed=3)


def test_sim_devices_implement_the_protocols(world):
    proj = SimProjector(world)
    cam = SimCamera(world, source=proj)
    assert isinstance(proj, Projector) and isinstance(cam, Camera)
    assert (cam.width, cam.height) == (64, 48) and (proj.width, proj.height) == (32, 32)
    assert proj.describe()["kind"] == "sim" and cam.describe()["scene"] == "test"


def test_camera_sees_what_the_projector_shows(world):
    white = np.full((32, 32), 255, np.uint8)
    half = white.copy()
    half[:, :16] = 0
    with SimProjector(world) as proj, SimCamera(world, source=proj) as cam:
        proj.load([white, half])
        assert proj.showing is None
        dark = cam.grab(after_s=0.0, timeout_s=1.0)
        shown = proj.show(0)
        assert shown.index == 0 and shown.host_time_s <= time.monotonic()
        lit = cam.grab(after_s=shown.host_time_s, timeout_s=1.0)
        assert lit.timestamp_s > shown.host_time_s and lit.sequence == dark.sequence + 1
        proj.show(1)
        assert proj.showing is not None and proj.showing[0, 0] == 0
        halfway = cam.grab(after_s=0.0, timeout_s=1.0)
        proj.stop()
        again = cam.grab(after_s=0.0, timeout_s=1.0)
    expected_dark = np.where(np.isfinite(world.truth.depth_cam), round(255 * 0.8 * 0.1), 0)
    assert np.array_equal(dark.image, expected_dark) and np.array_equal(again.image, dark.image)
    lit_px = world.truth.lit
    assert lit_px.sum() > 100
    assert np.all(lit.image[lit_px] > 150)
    # half the projector dark: lit pixels whose projector column is < 15 stay at ambient level
    q = world.truth.q_proj
    left = lit_px & (q[..., 0] < 14.5)
    right = lit_px & (q[..., 0] > 16.5)
    assert left.sum() > 20 and right.sum() > 20
    assert np.all(halfway.image[left] == expected_dark[left]) and np.all(halfway.image[right] > 150)


def test_lifecycle_and_errors(world):
    proj = SimProjector(world)
    cam = SimCamera(world, source=proj)
    with pytest.raises(DeviceError, match="not loaded"):
        proj.show(0)
    with pytest.raises(DeviceError, match="projector's resolution"):
        proj.load([np.zeros((10, 10), np.uint8)])
    with pytest.raises(DeviceTimeout):
        cam.grab(after_s=time.monotonic() + 5.0, timeout_s=0.05)
    t = time.monotonic() + 0.05
    assert cam.grab(after_s=t, timeout_s=1.0).timestamp_s > t  # waits for a frame after `after_s`
    proj.close()
    proj.close()
    cam.close()
    cam.close()
    assert proj.showing is None
    with pytest.raises(DeviceError, match="closed"):
        proj.show(0)
    with pytest.raises(DeviceError, match="closed"):
        cam.grab(after_s=0.0, timeout_s=1.0)


def test_camera_works_with_any_projector_source(world):
    class Fixed:
        """A minimal foreign Projector (e.g. the serial driver) that always shows white."""

        showing = np.full((32, 32), 255, np.uint8)

    with SimCamera(world, source=Fixed()) as cam:
        img = cam.grab(after_s=0.0, timeout_s=1.0).image
    assert np.all(img[world.truth.lit] > 150)


def test_world_noise_sequence_is_reproducible(world):
    rig, opts = world.rig, RenderOptions(noise_grey=3.0, supersample=1)
    a = SimWorld(rig, options=opts, seed=9)
    b = SimWorld(rig, options=opts, seed=9)
    frames_a = [a.render(None) for _ in range(2)]
    frames_b = [b.render(None) for _ in range(2)]
    assert np.array_equal(frames_a[0], frames_b[0]) and np.array_equal(frames_a[1], frames_b[1])
    assert not np.array_equal(frames_a[0], frames_a[1])
    assert a.truth.depth_cam.flags.writeable is False
