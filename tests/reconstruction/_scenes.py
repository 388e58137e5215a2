"""Constructed simulator scenes that several reconstruction tests share.

The collinear plate (decision 0084): a plane and, in front of it, a plate whose line j = 6 continues the plane's
line j = 0 in the image (the plate carries light sheet 6 on the 3-D line where sheet 6 meets the camera plane
through the plane's line 0), albedos set so that both lines are equally bright (the renderer has no distance
fall-off: radiance = albedo·cos θ_p·P). The one case where a line on two surfaces looks like one straight line in
the image, so the tangent tests cannot see the depth edge. Both devices are distortion-free pinholes, so the
construction is exact."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.patterns import GridPattern

#: the working volume of the pinhole rig's scenes (mm)
PINHOLE_DEPTH_RANGE = (500.0, 1200.0)
#: the pattern the pinhole rig's scenes are shown (800x600 projector)
PINHOLE_PATTERN = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), line_width_px=3.0)


def pinhole_procam() -> ProCam:
    """640x480 camera (f = 900 px) 190 mm beside an 800x600 projector (f = 1000 px), both aimed at (0, 0, 800)."""
    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.zeros(5))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.zeros(5))
    t = np.array([180.0, 60.0, 40.0])
    return ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)


def sheet_j(k: int) -> np.ndarray:
    """Normal N of PINHOLE_PATTERN's light sheet j = k (N·X = 0 in the projector frame): (y − n2·x)·f = k·pitch."""
    return np.array([PINHOLE_PATTERN.n2, -1.0, k * PINHOLE_PATTERN.pitch_px / 1000.0])


def planes_meet(n1, d1, n2, d2):
    """The line where planes n1·X = d1 and n2·X = d2 meet: a point and the unit direction."""
    u = np.cross(n1, n2)
    u /= np.linalg.norm(u)
    return np.linalg.solve(np.array([n1, n2, u]), [d1, d2, 0.0]), u


def project(procam: ProCam, X: np.ndarray) -> np.ndarray:
    """Camera pixel of projector-frame point X (pinhole camera)."""
    x = procam.R_proj_cam.T @ (X - procam.t_proj_cam)
    return procam.camera.K[:2, :2] @ (x[:2] / x[2]) + procam.camera.K[:2, 2]


def render_pinhole(objects):
    """(image, truth) of PINHOLE_PATTERN on `objects` seen by pinhole_procam (noise 2 grey levels, seed 0)."""
    from drivers.sim import RenderOptions, Scene, render

    return render(pinhole_procam(), Scene(objects=objects), PINHOLE_PATTERN.render(800, 600),
                  options=RenderOptions(noise_grey=2.0, supersample=2), rng=np.random.default_rng(0))


@lru_cache(maxsize=1)
def collinear_plate():
    """(procam, image, truth, edge): the plane at ~940 mm and the 100 × 100 × 20 mm plate ~240 mm in front of it
    (module doc); edge: the camera pixel where the plate's line j = 6 leaves the plate (its lit side). Rendered once
    per test session; treat the arrays as read-only."""
    from drivers.sim import Box, Plane

    procam = pinhole_procam()
    C = procam.t_proj_cam
    n_bg = np.array([0.1, -0.2, -1.0])
    n_bg /= np.linalg.norm(n_bg)
    p_bg = np.array([0, 0, 950.0])
    X2, u2 = planes_meet(sheet_j(0), 0.0, n_bg, n_bg @ p_bg)  # the plane's line j = 0
    n_cam = np.cross(X2 - C, u2)  # the camera plane through it
    n_cam /= np.linalg.norm(n_cam)
    X1, u1 = planes_meet(sheet_j(6), 0.0, n_cam, n_cam @ C)  # sheet 6 in that camera plane: the plate's line j = 6
    Xc = X1 + ((np.array([0, 0, 700.0]) - X1) @ u1) * u1
    v = C - Xc
    n_plate = v - (v @ u1) * u1
    n_plate /= np.linalg.norm(n_plate)
    R = np.column_stack([u1, np.cross(n_plate, u1), n_plate])
    cos_plate = n_plate @ (-Xc / np.linalg.norm(Xc))
    cos_bg = abs(n_bg @ (-X2 / np.linalg.norm(X2)))
    plate = Box(Xc - n_plate * 10.0, np.array([100.0, 100.0, 20.0]), R, albedo=min(1.0, 0.8 * cos_bg / cos_plate))
    image, truth = render_pinhole([Plane(p_bg, n_bg), plate])
    return procam, image, truth, project(procam, Xc + 50.0 * u1)


def unseen_render(seed: int):
    """Scene `seed` of benchmarks.unseen, rendered as that benchmark renders it (noise seeded with `seed`), with
    one OpenCV thread: (procam, pattern, image, truth, working volume (min, max) mm)."""
    import cv2

    from benchmarks._common import render_scene
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range

    cv2.setNumThreads(1)
    _rig, procam, scene, pattern, noise = draw_scene(seed)
    img, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=seed)
    return procam, pattern, img, truth, depth_range(procam, scene)


def unseen_frame(seed: int):
    """unseen_render's scene through the extraction stage with the default options and its working volume:
    (procam, pattern, truth, options, frame); finish_frame(replace(frame, options=…)) runs the label stage with other
    options."""
    from reconstruction.pipeline import ReconstructOptions, extract_frame

    procam, pattern, img, truth, dr = unseen_render(seed)
    o = ReconstructOptions(depth_min_mm=dr[0], depth_max_mm=dr[1])
    return procam, pattern, truth, o, extract_frame(img, procam, pattern, options=o)
