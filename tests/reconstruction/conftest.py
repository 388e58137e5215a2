"""A small simulated rig for the reconstruction tests: 640x480 camera with distortion, 800x600 projector
with distortion, a tilted plane and a sphere, rendered once per session with drivers.sim (~2 s)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.patterns import GridPattern


@dataclass(frozen=True)
class SmallScene:
    procam: ProCam
    pattern: GridPattern
    image: np.ndarray
    truth: object
    depth_range_mm: tuple[float, float]


def small_procam() -> ProCam:
    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.array([-0.05, 0.02, 0, 0, 0]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.array([0.03, 0, 0, 0, 0]))
    t = np.array([180.0, 60.0, 40.0])
    return ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)


def _render_small(pattern: GridPattern) -> SmallScene:
    """The small rig's tilted plane and sphere shown `pattern`, noise 2 grey levels, seeded."""
    from drivers.sim import Plane, RenderOptions, Scene, Sphere, render

    procam = small_procam()
    scene = Scene(objects=[Plane(np.array([0, 0, 900.0]), np.array([0.1, -0.2, -1.0])), Sphere(np.array([30.0, 20.0, 760.0]), 90.0)])
    image, truth = render(
        procam, scene, pattern.render(800, 600), options=RenderOptions(noise_grey=2.0, supersample=2), rng=np.random.default_rng(0)
    )
    return SmallScene(procam, pattern, image, truth, (500.0, 1200.0))


@pytest.fixture(scope="session")
def small_scene() -> SmallScene:
    return _render_small(GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), line_width_px=3.0))


@pytest.fixture(scope="session")
def small_scene_pitch16() -> SmallScene:
    """The same rig and scene shown a grid of pitch 16: the junction step in the camera (~7 px) is shorter than
    the gap a crossing leaves in a trace (decisions 0072, 0074)."""
    return _render_small(GridPattern(pitch_px=16.0, lines=37, centre_px=(399.5, 299.5), line_width_px=3.0))
