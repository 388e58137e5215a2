"""Which of two crossing lines is the i-line: the epipolar order (decision 0083).

Where the projector light grazes a surface (N·r → 0, r the projector ray) both light sheets' traces turn
towards the image of r, the epipolar line, and the two families cross at acute angles in the image (22–30°
on the tabletop's box sides, 33–37° on the converged rigs' sheared faces). There extraction's family test,
which compares a sample's direction with the directions predicted for a front-facing plane
(`RigModel.dir_cam`), can give both lines one family (decision 0076). The predicted directions depend on the
surface; the ORDER of the two families around the epipolar direction does not:

Near a surface point the projector→camera map is affine, A = ∂q_cam/∂q_proj. It maps the projector's
epipolar line through the point onto the camera's (both are the image of one epipolar plane), so it maps
the epipolar direction e_proj to e_cam. Projecting a surface patch onto an image keeps or reverses its
orientation according to which side of the patch the device sees; a lit, visible point is seen from its
front by both devices, so det A has one sign for every such surface at a given pixel (a property of the
rig). A linear map with det > 0 keeps the cyclic order of any three line directions and det < 0 reverses
it; hence the cyclic order of (e_cam, i-line, j-line) at a camera pixel is the same for every lit, visible
surface, whatever its depth and normal, and the model's prediction for one front-facing plane gives it
(`order_table`). Two lines crossing at a pixel are the i- and j-line in the order that matches; swapped
families give the other order. Checked against the simulator's truth at every visible true junction of
the 8 benchmark scenes (4 117, 141 of them under 45°, down to 0.5°), decision 0083.

The epipolar direction at a pixel is that of the line to the epipole, pinhole (lens distortion neglected:
it bends epipolar lines by a fraction of a degree over the image; the order is lost only for a line within
that much of the epipolar direction). This module is a building block: extraction does not use it yet
(decision 0083 says why: on the bench scenes the acute crossings are lost before a family decision,
for want of crossing candidates and samples).
"""

from __future__ import annotations

import numpy as np

from reconstruction.rigmodel import RigModel

__all__ = ["epipole_px", "epipolar_dir_cam", "order_sign", "order_table", "expected_order_sign"]

_TABLES: dict = {}


def epipole_px(model: RigModel) -> np.ndarray:
    """(3,) the epipole (image of the projector centre) in homogeneous camera pixels, pinhole: the epipolar
    direction at pixel (x, y) is (e0 − e2·x, e1 − e2·y) (sign-free; also with the epipole at infinity)."""
    c = model.procam.proj_to_cam(np.zeros(3))[0]  # projector centre, camera frame (mm)
    cam = model.procam.camera
    return np.array([cam.fx * c[0] + cam.cx * c[2], cam.fy * c[1] + cam.cy * c[2], c[2]])


def epipolar_dir_cam(model: RigModel, q_cam: np.ndarray) -> np.ndarray:
    """(N, 2) unit image directions (sign arbitrary) of the epipolar lines through camera pixels q_cam (N, 2)."""
    q = np.asarray(q_cam, np.float64).reshape(-1, 2)
    E = epipole_px(model)
    d = np.column_stack([E[0] - E[2] * q[:, 0], E[1] - E[2] * q[:, 1]])
    n = np.hypot(d[:, 0], d[:, 1])
    return d / np.where(n > 0, n, 1.0)[:, None]


def order_sign(e: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) int: the cyclic order of three line directions (N, 2) each (sign-free, period 180°): +1 when,
    turning from e in the direction of increasing image angle (atan2(y, x)), a comes before b; −1 otherwise."""
    e, a, b = (np.asarray(x, np.float64).reshape(-1, 2) for x in (e, a, b))
    ang_e = np.arctan2(e[:, 1], e[:, 0])
    ta = np.mod(np.arctan2(a[:, 1], a[:, 0]) - ang_e, np.pi)
    tb = np.mod(np.arctan2(b[:, 1], b[:, 0]) - ang_e, np.pi)
    return np.where(ta < tb, 1, -1)


def order_table(model: RigModel) -> np.ndarray:
    """(gh, gw) int8: the cyclic order of (epipolar direction, i-line, j-line) that every lit, visible surface
    shows, on the model's direction grid (`dir_cam`, pixel (c·cell_px, r·cell_px) at [r, c]), from the
    directions predicted for a front-facing plane; 0 where a predicted line is within 2° of the epipolar
    direction (order undecided). Cached per model."""
    hit = _TABLES.get(id(model))
    if hit is not None and hit[0] is model:
        return hit[1]
    gh, gw = model.dir_cam.shape[:2]
    r, c = np.mgrid[0:gh, 0:gw]
    q = np.column_stack([c.ravel(), r.ravel()]).astype(np.float64) * model.cell_px
    e = epipolar_dir_cam(model, q)
    d = model.dir_cam.reshape(-1, 2, 2)
    tab = order_sign(e, d[:, 0], d[:, 1]).astype(np.int8)
    for f in (0, 1):
        s = np.abs(e[:, 0] * d[:, f, 1] - e[:, 1] * d[:, f, 0])
        tab[s < np.sin(np.deg2rad(2.0))] = 0
    tab = tab.reshape(gh, gw)
    tab.setflags(write=False)
    if len(_TABLES) > 16:
        _TABLES.clear()
    _TABLES[id(model)] = (model, tab)
    return tab


def expected_order_sign(model: RigModel, q_cam: np.ndarray) -> np.ndarray:
    """(N,) int8: `order_table` at the nearest grid node of each camera pixel q_cam (N, 2)."""
    q = np.asarray(q_cam, np.float64).reshape(-1, 2)
    tab = order_table(model)
    gh, gw = tab.shape
    c = np.clip(np.rint(q[:, 0] / model.cell_px).astype(np.intp), 0, gw - 1)
    r = np.clip(np.rint(q[:, 1] / model.cell_px).astype(np.intp), 0, gh - 1)
    return tab[r, c]
