"""Epipolar geometry and triangulation for the camera–projector pair.

Everything here works in *normalised undistorted* coordinates (x, y) = (X/Z, Y/Z) of each device, so
that lens distortion of the camera and of the projector is removed once, at the boundary
(`Intrinsics.pixels_to_normalised`), and every relation below is exactly projective. The world frame is
the projector's (CONVENTIONS.md): a camera point p_cam maps to p_proj = R · p_cam + t, so the camera
centre is t and a camera ray with normalised direction w_cam = (x, y, 1) runs along d = R · w_cam.

Derivations: docs/reconstruction.md.
"""

from __future__ import annotations

import numpy as np

from calibration.models import ProCam


def camera_rays_proj(procam: ProCam, xy_cam: np.ndarray) -> np.ndarray:
    """Directions (N, 3) in the world (projector) frame of the camera rays through normalised points (N, 2)."""
    xy_cam = np.asarray(xy_cam, dtype=np.float64).reshape(-1, 2)
    w = np.column_stack([xy_cam, np.ones(len(xy_cam))])
    return w @ procam.R_proj_cam.T


def epipolar_lines(procam: ProCam, xy_cam: np.ndarray) -> np.ndarray:
    """Epipolar lines in the projector's normalised plane of camera points (N, 2) (normalised, undistorted).

    Returns (N, 3) homogeneous lines l with l · (x, y, 1) = 0 for every projector point (x, y) that can
    see the same 3-D point, scaled so that hypot(l0, l1) = 1: `l · (x, y, 1)` is then a signed distance in
    normalised projector units (multiply by the projector's focal length for pixels).

    The line joins the epipole (the camera centre t seen by the projector) and the vanishing point of the
    ray direction d = R · (x, y, 1): l = t × d (the paper's Eq. 3 with t and d written homogeneously).
    """
    d = camera_rays_proj(procam, xy_cam)
    t = procam.t_proj_cam
    lines = np.cross(np.broadcast_to(t, d.shape), d)
    norm = np.hypot(lines[:, 0], lines[:, 1])
    norm[norm == 0] = np.nan
    return lines / norm[:, None]


def paper_epipolar_mb(procam: ProCam, xy_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's Eq. 3, literally: slope m and intercept b (f_p units) of the epipolar lines y = m·x + b.

    Coordinates on the projector plane are the paper's: (f_p · x, f_p · y) for normalised (x, y), origin on
    the optical axis. w = R · (r, s, f_c) is proportional to R · (x, y, 1), and m, b are invariant to that
    scale, so normalised camera coordinates are used with f_c = 1 and f_p = 1: b comes out in normalised
    projector units (multiply by f_p for pixels). Vertical epipolar lines give infinite m (inf / nan).
    """
    w = camera_rays_proj(procam, xy_cam)
    t1, t2, t3 = procam.t_proj_cam
    w1, w2, w3 = w[:, 0], w[:, 1], w[:, 2]
    den = t3 * w1 - t1 * w3
    with np.errstate(divide="ignore", invalid="ignore"):
        m = (t3 * w2 - t2 * w3) / den
        b = (t2 * w1 - t1 * w2) / den
    return m, b


def triangulate_rays(procam: ProCam, xy_cam: np.ndarray, xy_proj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest approach of camera rays and projector rays (both given as normalised points, (N, 2)).

    The camera ray is t + λ·d (d = R·(x_c, y_c, 1)), the projector ray μ·e (e = (x_p, y_p, 1)). Minimising
    |t + λd − μe|² gives the 2×2 system [[d·d, −d·e], [d·e, −e·e]] (λ, μ) = (−d·t, −e·t); the point is the
    midpoint of the two closest points. Returns p_proj (N, 3) in mm and the gap between the rays (N,) in mm
    (NaN where the rays are parallel).
    """
    d = camera_rays_proj(procam, xy_cam)
    xy_proj = np.asarray(xy_proj, dtype=np.float64).reshape(-1, 2)
    e = np.column_stack([xy_proj, np.ones(len(xy_proj))])
    t = procam.t_proj_cam
    a = np.einsum("ij,ij->i", d, d)
    b = np.einsum("ij,ij->i", d, e)
    c = np.einsum("ij,ij->i", e, e)
    dt = d @ t
    et = e @ t
    det = b * b - a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        det = np.where(np.abs(det) < 1e-15 * a * c, np.nan, det)
        lam = (c * dt - b * et) / det
        mu = (b * dt - a * et) / det
    p_c = t + lam[:, None] * d
    p_p = mu[:, None] * e
    return 0.5 * (p_c + p_p), np.linalg.norm(p_c - p_p, axis=1)


def intersect_planes(procam: ProCam, xy_cam: np.ndarray, normals_proj: np.ndarray) -> np.ndarray:
    """Intersect camera rays (normalised points, (N, 2)) with planes through the projector centre.

    normals_proj (N, 3): plane normals N (plane N · p = 0). The ray t + λd meets it at λ = −N·t / N·d.
    Returns p_proj (N, 3) in mm; NaN where the ray is (nearly) parallel to the plane or meets it behind
    the camera.
    """
    d = camera_rays_proj(procam, xy_cam)
    N = np.asarray(normals_proj, dtype=np.float64).reshape(-1, 3)
    t = procam.t_proj_cam
    nd = np.einsum("ij,ij->i", N, d)
    nt = N @ t
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -nt / nd
    bad = ~(lam > 0) | (np.abs(nd) < 1e-9 * np.linalg.norm(N, axis=1) * np.linalg.norm(d, axis=1))
    lam = np.where(bad, np.nan, lam)
    return t + lam[:, None] * d


def depth_cam(procam: ProCam, p_proj: np.ndarray) -> np.ndarray:
    """Camera-frame z (mm) of world points (N, 3)."""
    p = np.asarray(p_proj, dtype=np.float64).reshape(-1, 3) - procam.t_proj_cam
    return p @ procam.R_proj_cam[:, 2]
