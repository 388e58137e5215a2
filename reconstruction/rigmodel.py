"""Per-rig precomputations shared by every frame: the pattern's junction rays, the light planes, the
expected image orientation of both line families, and the labelling condition number.

Built once per (ProCam, GridPattern) pair (`rig_model`, cached) and read-only afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from calibration.models import ProCam
from reconstruction.geometry import epipolar_lines, intersect_planes, triangulate_rays
from reconstruction.patterns import GridPattern

#: label value of a junction or point that has no (i, j) / line index
UNLABELLED = np.iinfo(np.int32).min

_CELL_PX = 32  # spacing of the orientation-prediction grid in camera pixels


@dataclass(frozen=True, eq=False)
class RigModel:
    """Read-only tables for one camera–projector pair and one pattern.

    index_min, index_max: the pattern's line indices (both families share them).
    xy_junction: (L, L, 2) normalised undistorted projector coordinates of junction (i, j) at
        [i − index_min, j − index_min].
    fx_proj: projector focal length (px per normalised unit), turns normalised distances into pixels.
    z_ref_mm: the depth (projector frame) of the plane the orientation prediction assumes.
    dir_cam: (gh, gw, 2, 2) unit image directions of the i-lines [..., 0, :] and j-lines [..., 1, :]
        on a coarse grid of camera pixels (cell `cell_px`), for a surface at z_ref_mm.
    J_proj_cam: (gh, gw, 2, 2) Jacobian d(projector px)/d(camera px) on the same grid.
    min_separation_px: smallest projector-pixel distance, across the pattern, between a junction's
        epipolar line and a junction a few labels away (the labelling's margin; small = ill-posed).
    """

    procam: ProCam
    pattern: GridPattern
    index_min: int
    index_max: int
    xy_junction: np.ndarray
    fx_proj: float
    z_ref_mm: float
    cell_px: int
    dir_cam: np.ndarray
    J_proj_cam: np.ndarray
    min_separation_px: float

    @property
    def cam_per_proj_px(self) -> float:
        """Typical camera pixels per projector pixel (square root of the Jacobian's determinant), at z_ref_mm."""
        det = np.abs(np.linalg.det(self.J_proj_cam.reshape(-1, 2, 2)))
        return float(np.median(1.0 / np.sqrt(det[det > 0]))) if np.any(det > 0) else 1.0

    @property
    def line_width_cam_px(self) -> float:
        """Typical width of a projected line in the camera image (px), at z_ref_mm."""
        return float(self.pattern.line_width_px * self.cam_per_proj_px)

    @property
    def junction_step_cam_px(self) -> float:
        """Typical distance in the camera (px) between neighbouring junctions along a line, at z_ref_mm."""
        p, n1, n2 = self.pattern.pitch_px, self.pattern.n1, self.pattern.n2
        along = min(np.hypot(1, n1), np.hypot(1, n2)) * p / abs(n2 - n1)
        return float(along * self.cam_per_proj_px)

    def junction_xy(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Normalised projector coordinates (N, 2) of junctions with integer labels inside the pattern."""
        return self.xy_junction[np.asarray(i) - self.index_min, np.asarray(j) - self.index_min]

    def in_pattern(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        i = np.asarray(i)
        j = np.asarray(j)
        return (i >= self.index_min) & (i <= self.index_max) & (j >= self.index_min) & (j <= self.index_max)

    def lookup(self, q_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted family directions (N, 2, 2) and Jacobians (N, 2, 2) at camera pixels (N, 2)."""
        gh, gw = self.dir_cam.shape[:2]
        c = np.clip(np.rint(q_cam[:, 0] / self.cell_px).astype(np.intp), 0, gw - 1)
        r = np.clip(np.rint(q_cam[:, 1] / self.cell_px).astype(np.intp), 0, gh - 1)
        return self.dir_cam[r, c], self.J_proj_cam[r, c]

    def light_plane_normals(self, family: np.ndarray, index: np.ndarray, other: np.ndarray) -> np.ndarray:
        """Normals (N, 3) of the light planes of lines (family 1: i-line `index`, 2: j-line `index`) near
        the crossing with the other family's (fractional) index `other`.

        Each line is straight in projector pixels; with projector distortion its light sheet is slightly
        curved, so the plane is taken through the projector rays of the line's points at other ± 1/2 (for
        a sample between two junctions, exactly the plane through both junction rays).
        """
        other = np.asarray(other, dtype=np.float64)
        lo = np.clip(other - 0.5, self.index_min, self.index_max)
        hi = np.clip(other + 0.5, self.index_min, self.index_max)
        same = hi - lo < 0.25
        lo = np.where(same & (lo > self.index_min), lo - 0.5, lo)
        hi = np.where(same & ~(lo > self.index_min), hi + 0.5, hi)
        return self._plane_through(family, index, lo, hi)

    def _plane_through(self, family, index, other_a, other_b) -> np.ndarray:
        """Normals (N, 3) of the planes through the projector rays of line (family, index) at the other
        family's (fractional) indices other_a and other_b."""
        family = np.asarray(family)
        index = np.asarray(index, dtype=np.float64)
        other_a = np.broadcast_to(np.asarray(other_a, np.float64), index.shape)
        other_b = np.broadcast_to(np.asarray(other_b, np.float64), index.shape)
        i_a = np.where(family == 1, index, other_a)
        j_a = np.where(family == 1, other_a, index)
        i_b = np.where(family == 1, index, other_b)
        j_b = np.where(family == 1, other_b, index)
        uv = self.pattern.junction_uv(np.concatenate([i_a, i_b]), np.concatenate([j_a, j_b]))
        xy = self.procam.projector.pixels_to_normalised(uv)
        n = len(index)
        a = np.column_stack([xy[:n], np.ones(n)])
        b = np.column_stack([xy[n:], np.ones(n)])
        return np.cross(a, b)

    def fractional_index(self, family: np.ndarray, uv_proj: np.ndarray) -> np.ndarray:
        """(N,) fractional index, in `family`'s own numbering (1: i, 2: j), of the line of that family
        through projector pixels uv_proj (N, 2) (uniform or De Bruijn spacing; clamped to the pattern)."""
        family = np.asarray(family)
        uv = np.asarray(uv_proj, np.float64).reshape(-1, 2)
        x = uv[:, 0] - self.pattern.centre_px[0]
        y = uv[:, 1] - self.pattern.centre_px[1]
        idx = self.pattern.indices.astype(np.float64)
        out = np.full(len(uv), np.nan)
        for f, n in ((1, self.pattern.n1), (2, self.pattern.n2)):
            sel = family == f
            if sel.any():
                out[sel] = np.interp(y[sel] - n * x[sel], self.pattern.offsets_px(f), idx)
        return out

    def intersect_light_sheets(self, xy_cam: np.ndarray, family: np.ndarray, index: np.ndarray, *, iterations: int = 2) -> np.ndarray:
        """Points p_proj (N, 3), mm: camera rays (normalised points xy_cam (N, 2)) ∩ the light sheets of
        lines (family (N,) 1 or 2, index (N,)).

        A line is straight in projector pixels, so with projector distortion its sheet of light is slightly
        curved. First the plane through the line's two ends; then, `iterations` times, the sheet's tangent
        plane where the previous point projects (through the rays of the line's points 0.02 crossings either
        side). Without projector distortion the first plane is exact. NaN where the ray misses.
        """
        family = np.asarray(family)
        index = np.asarray(index, np.float64)
        N = self._plane_through(family, index, self.index_min, self.index_max)
        p = intersect_planes(self.procam, xy_cam, N)
        if not self.procam.projector.has_distortion:
            return p
        other_family = np.where(family == 1, 2, 1)
        for _ in range(iterations):
            ok = np.isfinite(p).all(axis=1) & (p[:, 2] > 0)
            if not ok.any():
                break
            uv = np.full((len(p), 2), np.nan)
            uv[ok] = self.procam.projector.project(p[ok])
            other = self.fractional_index(other_family, uv)
            other = np.where(np.isfinite(other), other, 0.5 * (self.index_min + self.index_max))
            # the sheet's tangent plane there: through the rays of the line's points a short step either side
            p = intersect_planes(self.procam, xy_cam, self._plane_through(family, index, other - 0.02, other + 0.02))
        return p


def _reference_depth(procam: ProCam, depth_range_mm: tuple[float, float]) -> float:
    """Depth where the camera's optical axis passes closest to the projector's (the rig's working point)."""
    p, _ = triangulate_rays(procam, np.zeros((1, 2)), np.zeros((1, 2)))
    z = float(p[0, 2])
    lo, hi = depth_range_mm
    if not np.isfinite(z) or z <= 0:
        z = float(np.sqrt(lo * hi))
    return float(np.clip(z, lo, hi))


def _min_separation(procam: ProCam, pattern: GridPattern, xy_junction: np.ndarray, fx: float) -> float:
    """Smallest distance (projector px) from a junction's own epipolar line to junctions 1–3 labels away."""
    L = xy_junction.shape[0]
    step = max(1, L // 9)
    sel = np.arange(0, L, step)
    ii, jj = np.meshgrid(sel, sel, indexing="ij")
    xy = xy_junction[ii.ravel(), jj.ravel()]
    # The epipolar line of a junction is that of any camera pixel seeing it; take the ray at 1 m.
    p = np.column_stack([xy * 1000.0, np.full(len(xy), 1000.0)])
    p_cam = procam.proj_to_cam(p)
    ok = p_cam[:, 2] > 0
    if not ok.any():
        return float("nan")
    lines = epipolar_lines(procam, p_cam[ok, :2] / p_cam[ok, 2:3])
    i0, j0 = ii.ravel()[ok], jj.ravel()[ok]
    best = np.inf
    for di in range(-3, 4):
        for dj in range(-3, 4):
            if di == 0 and dj == 0:
                continue
            i1, j1 = i0 + di, j0 + dj
            inside = (i1 >= 0) & (i1 < L) & (j1 >= 0) & (j1 < L)
            if not inside.any():
                continue
            q = xy_junction[i1[inside], j1[inside]]
            d = np.abs(np.einsum("ij,ij->i", lines[inside, :2], q) + lines[inside, 2]) * fx
            best = min(best, float(np.nanmin(d)))
    return best


@lru_cache(maxsize=8)
def rig_model(procam: ProCam, pattern: GridPattern, depth_range_mm: tuple[float, float] = (100.0, 10000.0)) -> RigModel:
    """Build (or fetch from the cache) the tables for this pair and pattern."""
    idx = pattern.indices
    ii, jj = np.meshgrid(idx, idx, indexing="ij")
    uv = pattern.junction_uv(ii.ravel(), jj.ravel())
    xy = procam.projector.pixels_to_normalised(uv).reshape(len(idx), len(idx), 2)
    xy.setflags(write=False)
    fx = procam.projector.fx
    z_ref = _reference_depth(procam, depth_range_mm)

    cam = procam.camera
    gw = cam.width // _CELL_PX + 1
    gh = cam.height // _CELL_PX + 1
    gv, gu = np.mgrid[0:gh, 0:gw]
    q = np.column_stack([gu.ravel(), gv.ravel()]).astype(np.float64) * _CELL_PX
    d = cam.rays(q) @ procam.R_proj_cam.T
    t = procam.t_proj_cam
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (z_ref - t[2]) / d[:, 2]
    P = t + lam[:, None] * d
    uv0 = procam.projector.project(P)
    cols = []
    for du in ((1.0, 0.0), (0.0, 1.0)):
        xy1 = procam.projector.pixels_to_normalised(uv0 + np.array(du))
        P1 = np.column_stack([xy1 * z_ref, np.full(len(xy1), z_ref)])
        q1 = cam.project(procam.proj_to_cam(P1))
        cols.append(q1 - q)
    J_cam_proj = np.stack(cols, axis=-1)  # (N, 2, 2): d(cam px)/d(proj px)
    bad = ~(lam > 0) | ~np.isfinite(J_cam_proj).all(axis=(1, 2))
    with np.errstate(invalid="ignore"):
        det = np.linalg.det(np.where(bad[:, None, None], np.eye(2), J_cam_proj))
    bad |= np.abs(det) < 1e-9
    if bad.all():
        J_cam_proj[:] = np.eye(2)
    else:
        J_cam_proj[bad] = np.median(J_cam_proj[~bad], axis=0)
    dirs = []
    for n in (pattern.n1, pattern.n2):
        v = J_cam_proj @ np.array([1.0, n])
        dirs.append(v / np.linalg.norm(v, axis=1, keepdims=True))
    dir_cam = np.stack(dirs, axis=1).reshape(gh, gw, 2, 2)
    J_proj_cam = np.linalg.inv(J_cam_proj).reshape(gh, gw, 2, 2)
    for a in (dir_cam, J_proj_cam):
        a.setflags(write=False)
    return RigModel(
        procam=procam,
        pattern=pattern,
        index_min=int(idx[0]),
        index_max=int(idx[-1]),
        xy_junction=xy,
        fx_proj=fx,
        z_ref_mm=z_ref,
        cell_px=_CELL_PX,
        dir_cam=dir_cam,
        J_proj_cam=J_proj_cam,
        min_separation_px=_min_separation(procam, pattern, xy, fx),
    )
