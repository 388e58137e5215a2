"""Pinhole models with OpenCV distortion, and the camera–projector pair.

Pure functions on arrays; conventions in CONVENTIONS.md (pixel (0, 0) is the centre of the top-left pixel,
points are (N, 2) / (N, 3), millimetres, p_proj = R · p_cam + t).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)


def _as_dist(dist) -> np.ndarray:
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size not in _DIST_LENGTHS:
        raise ValueError(f"distortion must have one of {_DIST_LENGTHS} coefficients, got {d.size}")
    out = np.zeros(5 if d.size <= 5 else d.size)
    out[: d.size] = d
    return out


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """A pinhole camera (or projector, used backwards) with OpenCV's distortion model.

    width, height: image size in pixels. K: (3, 3). dist: OpenCV coefficients [k1, k2, p1, p2, k3, …].
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        K.setflags(write=False)
        d = _as_dist(self.dist)
        d.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0))

    # --- normalised (undistorted, z = 1) coordinates <-> pixels -------------------------------------------
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised undistorted coordinates (N, 2) -> normalised distorted coordinates (N, 2)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion:
            return xy.copy()
        if self.dist.size > 5:
            # Rational / thin-prism / tilt models: let OpenCV do it (rare for our rigs).
            pts = cv2.projectPoints(
                np.column_stack([xy, np.ones(len(xy))]).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.eye(3), self.dist
            )[0]
            return pts.reshape(-1, 2)
        k1, k2, p1, p2, k3 = self.dist[:5]
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.column_stack([xd, yd])

    def normalised_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Normalised undistorted (N, 2) -> pixel coordinates (N, 2), distortion applied."""
        d = self.distort(xy)
        return np.column_stack([self.fx * d[:, 0] + self.K[0, 1] * d[:, 1] + self.cx, self.fy * d[:, 1] + self.cy])

    def pixels_to_normalised(self, q: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) -> normalised undistorted coordinates (N, 2) (iterative inverse)."""
        q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
        if len(q) == 0:
            return np.zeros((0, 2))
        if not self.has_distortion:
            y = (q[:, 1] - self.cy) / self.fy
            x = (q[:, 0] - self.cx - self.K[0, 1] * y) / self.fx
            return np.column_stack([x, y])
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        # OpenCV 5 has no undistortPointsIter; undistortPoints takes the criteria but asserts a 3x3 P.
        out = cv2.undistortPoints(q.reshape(-1, 1, 2), self.K, self.dist, R=np.eye(3), P=np.eye(3), criteria=crit)
        return out.reshape(-1, 2)

    # --- 3-D <-> pixels --------------------------------------------------------------------------------------
    def project(self, p: np.ndarray) -> np.ndarray:
        """Points (N, 3) in this device's own frame -> pixels (N, 2). Points with z <= 0 give NaN."""
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        return self.normalised_to_pixels(xy)

    def rays(self, q: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) -> ray directions (N, 3) in this device's frame, scaled so that z = 1."""
        xy = self.pixels_to_normalised(q)
        return np.column_stack([xy, np.ones(len(xy))])

    def pixel_grid(self) -> np.ndarray:
        """All pixel centres as (H*W, 2) (u, v), row-major (row = v)."""
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        return np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)


@dataclass(frozen=True, eq=False)
class ProCam:
    """A calibrated camera–projector pair in the world (= projector) frame.

    R_proj_cam (3, 3) and t_proj_cam (3,) in mm: p_proj = R_proj_cam · p_cam + t_proj_cam.
    """

    camera: Intrinsics
    projector: Intrinsics
    R_proj_cam: np.ndarray
    t_proj_cam: np.ndarray

    def __post_init__(self) -> None:
        R = np.asarray(self.R_proj_cam, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.t_proj_cam, dtype=np.float64).reshape(3)
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R_proj_cam", R)
        object.__setattr__(self, "t_proj_cam", t)

    @property
    def baseline_mm(self) -> float:
        return float(np.linalg.norm(self.t_proj_cam))

    def cam_to_proj(self, p_cam: np.ndarray) -> np.ndarray:
        return np.asarray(p_cam, dtype=np.float64).reshape(-1, 3) @ self.R_proj_cam.T + self.t_proj_cam

    def proj_to_cam(self, p_proj: np.ndarray) -> np.ndarray:
        return (np.asarray(p_proj, dtype=np.float64).reshape(-1, 3) - self.t_proj_cam) @ self.R_proj_cam


def rotation_from_euler_deg(rx: float, ry: float, rz: float) -> np.ndarray:
    """R = Rz · Ry · Rx for rotations (degrees) about the x, y, z axes (applied x first)."""
    ax, ay, az = np.deg2rad([rx, ry, rz])
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, -1.0, 0.0])) -> np.ndarray:
    """Rotation R_world_dev whose z axis points from `eye` to `target`, x right, y down (OpenCV frame).

    `up` is the world direction that should appear up in the image (default −y: world y points down).
    """
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, float), z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(np.array([0.0, 0.0, 1.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])
