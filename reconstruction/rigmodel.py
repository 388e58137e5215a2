"""Per-rig precomputations shared by every frame: the pattern's junction rays, the light planes, the
expected image orientation of both line families, and the labelling margin (`reconstruction.placement`).

Built once per (ProCam, GridPattern, depth range) (`rig_model`, cached) and read-only afterwards.

Speed: the per-sample steps of triangulation (`cam_normalised`, `intersect_light_sheets`) are numba kernels
(decision 0065), short passes over the samples with the per-rig tables and no per-frame allocation beyond
their outputs. They compute what the NumPy formulation in each docstring describes (same operations,
float rounding aside). The triangulate stage does the same arithmetic from pixels to outputs in one call
(`pipeline._k_frame_points`, arguments from `pixel_sheet_tables`, decision 0071).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from calibration.models import ProCam
from reconstruction._jit import njit
from reconstruction._label_kernels import project_nearest_line as _project_nearest_line
from reconstruction.geometry import depth_cam, triangulate_rays
from reconstruction.patterns import GridPattern
from reconstruction.placement import LabellingMargin, labelling_margin

#: label value of a junction or point that has no (i, j) / line index
UNLABELLED = np.iinfo(np.int32).min

_CELL_PX = 32  # spacing of the orientation-prediction grid in camera pixels
_CAM_TABLE_PX = 4  # spacing of the camera undistortion table (bilinear in between, see cam_normalised)
_SHEET_NODES = 8  # light-sheet table: chord planes per crossing along each line


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
    margin: the labelling margin inside the working volume (`placement.labelling_margin` for this depth
        range): the pipeline warns when its verdict is "ill-posed", the same test `rig check` applies.
    line_offsets_px: (2, L) the offsets c of the lines y = n·x + c of family 1 [0] and 2 [1] (the
        pattern's `offsets_px`, uniform or De Bruijn), for `fractional_index`.
    cam_xy_table: (th, tw, 2) normalised undistorted camera coordinates of the pixels (k·s, l·s) at
        [l, k], s = cam_table_px (None without camera distortion): `cam_normalised` interpolates it.
    sheet_normals: (2, L, K − 1, 3) normals of the chord planes of every line's light sheet (family 1 at
        [0], 2 at [1]; line index − index_min; K = (L − 1)·sheet_nodes + 1 points along the line at the
        other family's fractional indices index_min + k/sheet_nodes). sheet_end_normals (2, L, 3): the
        plane through each line's two ends.
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
    margin: LabellingMargin
    line_offsets_px: np.ndarray
    cam_table_px: int = _CAM_TABLE_PX
    cam_xy_table: np.ndarray | None = None
    sheet_nodes: int = _SHEET_NODES
    sheet_normals: np.ndarray | None = None
    sheet_end_normals: np.ndarray | None = None

    @cached_property
    def cam_per_proj_px(self) -> float:
        """Typical camera pixels per projector pixel (square root of the Jacobian's determinant), at z_ref_mm."""
        det = np.abs(np.linalg.det(self.J_proj_cam.reshape(-1, 2, 2)))
        return float(np.median(1.0 / np.sqrt(det[det > 0]))) if np.any(det > 0) else 1.0

    @cached_property
    def line_width_cam_px(self) -> float:
        """Typical width of a projected line in the camera image (px), at z_ref_mm (cached per rig)."""
        return float(self.pattern.line_width_px * self.cam_per_proj_px)

    @cached_property
    def junction_step_cam_px(self) -> float:
        """Typical distance in the camera (px) between neighbouring junctions along a line, at z_ref_mm
        (cached per rig: the label stage reads it several times per frame, decision 0078)."""
        p, n1, n2 = self.pattern.pitch_px, self.pattern.n1, self.pattern.n2
        along = min(np.hypot(1, n1), np.hypot(1, n2)) * p / abs(n2 - n1)
        return float(along * self.cam_per_proj_px)

    @cached_property
    def line_spacing_perp_px(self) -> np.ndarray:
        """Each family's smallest line spacing perpendicular to its lines (2,) projector px (decision 0094:
        read by `surface_labels` once per frame)."""
        pat = self.pattern
        return np.min(np.diff(self.line_offsets_px, axis=1), axis=1) / np.hypot(1.0, np.array([pat.n1, pat.n2]))

    @cached_property
    def _sheet_check_args(self) -> tuple | None:
        """`_k_sheet_check`'s arguments after (q, family, index) up to its scratch arrays, built once per rig; None
        where `sheet_check` takes the NumPy path (no camera table, or more than 5 projector distortion
        coefficients) (decision 0094: ~6 µs of Python per call were half of a small call)."""
        proj = self.procam.projector
        if self.cam_xy_table is None or proj.dist.size > 5:
            return None
        return (self.cam_xy_table, 1.0 / self.cam_table_px, self.procam.R_proj_cam, self.procam.t_proj_cam, self.index_min,
                self.sheet_nodes, 1 if proj.has_distortion else 0, *self._sheet_kernel_tables, *self.nearest_line_tables)

    @cached_property
    def t_proj_cam_c(self) -> np.ndarray:
        """procam.t_proj_cam as a contiguous float64 (3,) for the kernels (decision 0094)."""
        return np.ascontiguousarray(self.procam.t_proj_cam, np.float64)

    @cached_property
    def _sheet_kernel_tables(self) -> tuple:
        """The arrays `_k_light_sheets` reads after its fixed arguments (all float64, C order)."""
        t = self.procam.t_proj_cam
        proj = self.procam.projector
        offs = self.line_offsets_px
        L = offs.shape[1]
        with np.errstate(divide="ignore"):
            inv_dx = 1.0 / np.diff(offs, axis=1) if L > 1 else np.zeros((2, 1))
            guess = (L - 1) / (offs[:, -1] - offs[:, 0]) if L > 1 else np.zeros(2)
        return (
            self.sheet_end_normals, np.ascontiguousarray(self.sheet_end_normals @ t),
            self.sheet_normals, np.ascontiguousarray(self.sheet_normals @ t),
            np.ascontiguousarray(proj.K), np.ascontiguousarray(proj.dist[:5]), np.asarray(self.pattern.centre_px, np.float64),
            np.array([self.pattern.n2, self.pattern.n1]), offs, np.ascontiguousarray(inv_dx), np.ascontiguousarray(guess),
        )

    @cached_property
    def pixel_sheet_tables(self) -> tuple[bool, tuple]:
        """(kernel_ok, tables): the arguments after R, t of the kernels that go from camera pixels to
        light-sheet points in one pass (`pipeline._k_frame_points`): index_min, sheet_nodes, iterations
        (1 with projector distortion, else 0, as `intersect_light_sheets`), the camera table (empty
        (0, 0, 2) without camera distortion: the pinhole inverse), 1/cam_table_px, the camera's K, then
        `_sheet_kernel_tables`. kernel_ok is False for a distorted projector with more than 5 coefficients
        (its projection is OpenCV's: use `intersect_light_sheets`)."""
        procam = self.procam
        proj = procam.projector
        distorted = proj.has_distortion
        tab = self.cam_xy_table if self.cam_xy_table is not None else np.zeros((0, 0, 2))
        tables = (
            np.ascontiguousarray(procam.R_proj_cam, np.float64), np.ascontiguousarray(procam.t_proj_cam, np.float64),
            self.index_min, self.sheet_nodes, 1 if distorted else 0, tab, 1.0 / self.cam_table_px,
            np.ascontiguousarray(procam.camera.K), *self._sheet_kernel_tables,
        )
        return not (distorted and proj.dist.size > 5), tables

    @cached_property
    def nearest_line_tables(self) -> tuple:
        """The arguments after (p, family) of `_label_kernels.project_nearest_line` for this rig (projector
        K, its first 5 distortion coefficients, distorted?, pattern centre, slopes n1 n2, line offsets (2, L),
        hypot(1, n) per family, line indices), built once per rig instead of per call (decision 0078)."""
        proj = self.procam.projector
        pat = self.pattern
        offs = np.ascontiguousarray(np.stack([np.asarray(pat.offsets_px(1), np.float64), np.asarray(pat.offsets_px(2), np.float64)]))
        return (np.ascontiguousarray(proj.K, np.float64), np.ascontiguousarray(proj.dist[:5], np.float64), bool(proj.has_distortion),
                float(pat.centre_px[0]), float(pat.centre_px[1]), np.array([pat.n1, pat.n2]), offs,
                np.array([np.hypot(1.0, pat.n1), np.hypot(1.0, pat.n2)]), np.ascontiguousarray(pat.indices, np.int64))

    def sheet_check(self, q_cam: np.ndarray, family: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For camera pixels q_cam (N, 2) on the light sheets of lines (family (N,) 1 or 2, integer index (N,)):
        the points p_proj (N, 3) mm, their camera-frame depth z (N,) mm, and the nearest line of the other
        family (3 − family) to their projector pixel: its index (N,) and distance (N,) projector px.

        Exactly `intersect_light_sheets(cam_normalised(q_cam), family, index)`, `geometry.depth_cam` and
        `continuation.project_nearest_line(model, 3 − family, p)`: one compiled call (`_k_sheet_check`) of
        the same kernels and arithmetic when the camera has a table, the projector at most 5 distortion
        coefficients and every pixel lies inside the table; otherwise those NumPy calls (decision 0078)."""
        q = np.ascontiguousarray(np.asarray(q_cam, np.float64).reshape(-1, 2))
        fam = np.ascontiguousarray(np.asarray(family).reshape(-1), dtype=np.intp)
        idx = np.ascontiguousarray(np.asarray(index).reshape(-1), dtype=np.intp)
        n = len(q)
        fixed = self._sheet_check_args
        if n and fixed is not None:
            p = np.empty((n, 3))
            z = np.empty(n)
            k, dist = _k_sheet_check(q, fam, idx, *fixed, np.empty((n, 2)), np.empty(n, np.bool_), p, np.empty(n), z)
            if k.shape[0] == n:
                return p, z, k, dist
        from reconstruction.continuation import project_nearest_line

        p = self.intersect_light_sheets(self.cam_normalised(q), fam, idx)
        k, dist = project_nearest_line(self, 3 - fam, p)
        return p, depth_cam(self.procam, p), k, dist

    def sheet_depth(self, q_cam: np.ndarray, family: np.ndarray, index: np.ndarray, *, xy_cam: np.ndarray | None = None) -> np.ndarray:
        """Camera-frame depth z (N,) mm of camera pixels q_cam (N, 2) on the light sheets of lines (family (N,)
        1 or 2, integer index (N,)): `sheet_check(q_cam, family, index)[1]`, to the bit, without the nearest
        line of the other family (decision 0094). xy_cam: `cam_normalised(q_cam)` when the caller has it
        (read only on the NumPy path, which computes it otherwise)."""
        q = np.ascontiguousarray(np.asarray(q_cam, np.float64).reshape(-1, 2))
        fam = np.ascontiguousarray(np.asarray(family).reshape(-1), dtype=np.intp)
        idx = np.ascontiguousarray(np.asarray(index).reshape(-1), dtype=np.intp)
        n = len(q)
        proj = self.procam.projector
        if n and self.cam_xy_table is not None and proj.dist.size <= 5:
            z = np.empty(n)
            if _k_sheet_depth(q, fam, idx, self.cam_xy_table, 1.0 / self.cam_table_px, self.procam.R_proj_cam, self.procam.t_proj_cam,
                              self.index_min, self.sheet_nodes, 1 if proj.has_distortion else 0, *self._sheet_kernel_tables, z):
                return z
        xy = self.cam_normalised(q) if xy_cam is None else xy_cam
        return depth_cam(self.procam, self.intersect_light_sheets(xy, fam, idx))

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
        idx = np.arange(self.index_min, self.index_max + 1, dtype=np.float64)
        out = np.full(len(uv), np.nan)
        for f, n in ((1, self.pattern.n1), (2, self.pattern.n2)):
            sel = family == f
            if sel.any():
                out[sel] = np.interp(y[sel] - n * x[sel], self.line_offsets_px[f - 1], idx)
        return out

    def cam_normalised(self, q_cam: np.ndarray) -> np.ndarray:
        """Camera pixels (N, 2) -> normalised undistorted coordinates (N, 2), like
        `Intrinsics.pixels_to_normalised` but from the per-rig table (bilinear between nodes 4 px apart;
        the undistortion is smooth, so the interpolation error is ~h²·|f''|/8, far below the sample noise;
        `test_recon_geometry` checks < 0.005 px with k1 = −0.2). Points outside the table use the exact inverse."""
        q = np.ascontiguousarray(np.asarray(q_cam, np.float64).reshape(-1, 2))
        tab = self.cam_xy_table
        if tab is None or len(q) == 0:
            return self.procam.camera.pixels_to_normalised(q)
        out = np.empty((len(q), 2))
        inside = np.empty(len(q), np.bool_)
        _k_cam_bilinear(q, tab, 1.0 / self.cam_table_px, out, inside)
        if not inside.all():
            out[~inside] = self.procam.camera.pixels_to_normalised(q[~inside])
        return out

    def intersect_light_sheets(self, xy_cam: np.ndarray, family: np.ndarray, index: np.ndarray, *, iterations: int = 1) -> np.ndarray:
        """Points p_proj (N, 3), mm: camera rays (normalised points xy_cam (N, 2)) ∩ the light sheets of
        lines (family (N,) 1 or 2, integer index (N,)).

        A line is straight in projector pixels, so with projector distortion its sheet of light is slightly
        curved. First the plane through the line's two ends (exact without projector distortion); then,
        `iterations` times, the chord plane of the sheet (from the per-rig table, 1/sheet_nodes of a
        crossing long) where the previous point projects. The chord is within ~1e-5 of the sheet and the
        first point's position along the line is off by far less than a chord, so one iteration is enough
        (round trip < 0.01 mm with k1 = 0.08 in `test_recon_geometry`). NaN where the ray misses.

        In NumPy terms, per point: d = R·(x, y, 1); p = ray ∩ end plane; then `iterations` times
        other = fractional_index(3 − family, projector.project(p)) (NaN -> the middle chord),
        seg = clip((other − index_min)·sheet_nodes, 0, K − 1) truncated, p = ray ∩ chord plane seg. One
        kernel pass (`_k_light_sheets`) for OpenCV's 5-coefficient distortion; projectors with a rational
        model (more coefficients) project with `Intrinsics.project` between kernel passes.
        """
        xy = np.ascontiguousarray(np.asarray(xy_cam, np.float64).reshape(-1, 2))
        family = np.ascontiguousarray(np.asarray(family).reshape(-1), dtype=np.intp)
        index = np.ascontiguousarray(np.asarray(index).reshape(-1), dtype=np.intp)
        procam = self.procam
        proj = procam.projector
        out = np.empty((len(xy), 3))
        if len(xy) == 0:
            return out
        if not proj.has_distortion:
            iterations = 0
        general = iterations > 0 and proj.dist.size > 5
        tabs = self._sheet_kernel_tables
        _k_light_sheets(
            xy, family, index, procam.R_proj_cam, procam.t_proj_cam, self.index_min, self.sheet_nodes,
            0 if general else max(int(iterations), 0), *tabs, out, np.empty(len(xy)),
        )
        if general:
            # Rational / thin-prism projector models: project with OpenCV, then the chord planes.
            li = np.clip(index - self.index_min, 0, self.index_max - self.index_min)
            K = self.sheet_normals.shape[2]
            for _ in range(iterations):
                other = self.fractional_index(3 - family, proj.project(out))  # NaN stays NaN
                seg = (other - self.index_min) * self.sheet_nodes
                seg = np.clip(np.where(np.isfinite(seg), seg, K // 2), 0, K - 1).astype(np.intp)
                out = _ray_plane(procam.t_proj_cam, xy @ procam.R_proj_cam[:, :2].T + procam.R_proj_cam[:, 2],
                                 self.sheet_normals[family - 1, li, seg])
        return out


def _ray_plane(t: np.ndarray, d: np.ndarray, N: np.ndarray) -> np.ndarray:
    """Camera rays t + λ·d (d (N, 3), |d| ≥ 1) ∩ planes N·p = 0 (unit normals N (N, 3)); NaN where the
    ray is parallel to the plane or meets it behind the camera (as geometry.intersect_planes)."""
    nd = N[:, 0] * d[:, 0] + N[:, 1] * d[:, 1] + N[:, 2] * d[:, 2]
    nt = N @ t
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -nt / nd
    lam[~(lam > 0) | (np.abs(nd) < 1e-9)] = np.nan
    return t + lam[:, None] * d


# --- kernels (decision 0065): plain loops over flat arrays, one pass per call ------------------------------


@njit
def _k_cam_bilinear(q, tab, inv_step, out, inside):
    """Bilinear lookup of the camera table tab (th, tw, 2) at pixels q (N, 2) scaled by inv_step into out
    (N, 2); inside[n] False (out undefined) where the point is not strictly inside the table (or NaN)."""
    th = tab.shape[0]
    tw = tab.shape[1]
    for n in range(q.shape[0]):
        x = q[n, 0] * inv_step
        y = q[n, 1] * inv_step
        if not (x >= 0.0 and y >= 0.0 and x < tw - 1 and y < th - 1):
            inside[n] = False
            out[n, 0] = np.nan
            out[n, 1] = np.nan
            continue
        inside[n] = True
        x0 = int(x)
        y0 = int(y)
        fx = x - x0
        fy = y - y0
        w00 = (1 - fx) * (1 - fy)
        w01 = fx * (1 - fy)
        w10 = (1 - fx) * fy
        w11 = fx * fy
        for c in range(2):
            out[n, c] = tab[y0, x0, c] * w00 + tab[y0, x0 + 1, c] * w01 + tab[y0 + 1, x0, c] * w10 + tab[y0 + 1, x0 + 1, c] * w11


@njit
def _k_light_sheets(xy, family, index, R, t, index_min, nodes, iterations,
                    end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, out, s_tmp):
    """out[n] = camera ray through xy[n] ∩ the light sheet of line (family[n], index[n]) (see
    RigModel.intersect_light_sheets; tables from RigModel._sheet_kernel_tables; end_t, chord_t: the planes'
    N·t). One pass over the end planes, then per iteration a pass projecting the points into the projector
    and a pass over the chord planes: short loops without calls keep numba's code tight."""
    N = xy.shape[0]
    L = end_n.shape[1]
    n_chords = chord_n.shape[2]
    # scalars in locals: the stores to out could alias the tables as far as the compiler knows
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    for n in range(N):
        f = family[n] - 1
        li = min(max(index[n] - index_min, 0), L - 1)
        d0 = xy[n, 0] * r00 + xy[n, 1] * r01 + r02
        d1 = xy[n, 0] * r10 + xy[n, 1] * r11 + r12
        d2 = xy[n, 0] * r20 + xy[n, 1] * r21 + r22
        nd = end_n[f, li, 0] * d0 + end_n[f, li, 1] * d1 + end_n[f, li, 2] * d2
        # λ of the ray on the plane N·p = 0: −N·t / N·d; NaN if parallel or behind the camera (as _ray_plane)
        lam = -end_t[f, li] / nd if abs(nd) >= 1e-9 else np.nan
        if not (lam > 0):
            lam = np.nan
        out[n, 0] = t0 + lam * d0
        out[n, 1] = t1 + lam * d1
        out[n, 2] = t2 + lam * d2
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    fx, skew, cx, fy, cy = K_proj[0, 0], K_proj[0, 1], K_proj[0, 2], K_proj[1, 1], K_proj[1, 2]
    cu, cv = centre[0], centre[1]
    n_other_1, n_other_2 = n_other[0], n_other[1]
    idx_min = float(index_min)
    top = float(n_chords - 1)
    mid = n_chords // 2
    for _ in range(iterations):
        # The offset s = y − n·x (projector px from the pattern centre) of the other family's line through
        # each point's projection (Intrinsics.project with OpenCV's 5-coefficient model; NaN behind).
        for n in range(N):
            pz = out[n, 2]
            x = out[n, 0] / pz if pz > 0 else np.nan
            y = out[n, 1] / pz if pz > 0 else np.nan
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            u = fx * xd + skew * yd + cx
            v = fy * yd + cy
            s_tmp[n] = (v - cv) - (n_other_1 if family[n] == 1 else n_other_2) * (u - cu)
        for n in range(N):
            f = family[n] - 1
            o = 1 - f  # the other family's row
            li = min(max(index[n] - index_min, 0), L - 1)
            # the other family's fractional index: np.interp(s, offsets[o], index_min + arange(L)), the
            # search started from the mean spacing (exact for uniform spacing)
            s = s_tmp[n]
            if s != s:
                seg = mid  # the point missed the end plane: the middle chord (as the NumPy path)
            else:
                if s <= offsets[o, 0]:
                    other = float(index_min)
                elif s >= offsets[o, L - 1]:
                    other = float(index_min + L - 1)
                else:
                    lo = min(max(int((s - offsets[o, 0]) * guess[o]), 0), L - 2)
                    while offsets[o, lo] > s:
                        lo -= 1
                    while offsets[o, lo + 1] <= s:
                        lo += 1
                    other = inv_dx[o, lo] * (s - offsets[o, lo]) + float(index_min + lo)
                seg = int(min(max((other - idx_min) * nodes, 0.0), top))
            d0 = xy[n, 0] * r00 + xy[n, 1] * r01 + r02
            d1 = xy[n, 0] * r10 + xy[n, 1] * r11 + r12
            d2 = xy[n, 0] * r20 + xy[n, 1] * r21 + r22
            nd = chord_n[f, li, seg, 0] * d0 + chord_n[f, li, seg, 1] * d1 + chord_n[f, li, seg, 2] * d2
            lam = -chord_t[f, li, seg] / nd if abs(nd) >= 1e-9 else np.nan
            if not (lam > 0):
                lam = np.nan
            out[n, 0] = t0 + lam * d0
            out[n, 1] = t1 + lam * d1
            out[n, 2] = t2 + lam * d2


@njit
def _k_sheet_check(q, family, index, tab, inv_step, R, t, index_min, nodes, iterations,
                   end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess,
                   K_nl, dist_nl, distorted, cu, cv, n12, offs, hyp, indices, xy, inside, out, s_tmp, z):
    """`RigModel.sheet_check` in one call: the camera table (`_k_cam_bilinear`), the light sheets
    (`_k_light_sheets`), z = R[:, 2]·(p − t) (as `geometry.depth_cam`), then
    `_label_kernels.project_nearest_line` with family 3 − family. Returns (index, distance) of the nearest
    line, or two empty arrays when a pixel lies outside the table (the caller then takes the NumPy path)."""
    N = q.shape[0]
    _k_cam_bilinear(q, tab, inv_step, xy, inside)
    for n in range(N):
        if not inside[n]:
            return np.zeros(0, np.int64), np.zeros(0)
    _k_light_sheets(xy, family, index, R, t, index_min, nodes, iterations,
                    end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, out, s_tmp)
    r02, r12, r22 = R[0, 2], R[1, 2], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    other = np.empty(N, np.int64)
    for n in range(N):
        z[n] = (out[n, 0] - t0) * r02 + (out[n, 1] - t1) * r12 + (out[n, 2] - t2) * r22
        other[n] = 3 - family[n]
    return _project_nearest_line(out, other, K_nl, dist_nl, distorted, cu, cv, n12, offs, hyp, indices)


@njit
def _k_sheet_depth(q, family, index, tab, inv_step, R, t, index_min, nodes, iterations,
                   end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, z):
    """`RigModel.sheet_depth`'s compiled path: `_k_sheet_check`'s table, light sheets and depth, without the
    nearest line; writes z (N,) and returns True, or False when a pixel lies outside the table."""
    N = q.shape[0]
    xy = np.empty((N, 2))
    inside = np.empty(N, np.bool_)
    _k_cam_bilinear(q, tab, inv_step, xy, inside)
    for n in range(N):
        if not inside[n]:
            return False
    out = np.empty((N, 3))
    _k_light_sheets(xy, family, index, R, t, index_min, nodes, iterations,
                    end_n, end_t, chord_n, chord_t, K_proj, dist, centre, n_other, offsets, inv_dx, guess, out, np.empty(N))
    r02, r12, r22 = R[0, 2], R[1, 2], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    for n in range(N):
        z[n] = (out[n, 0] - t0) * r02 + (out[n, 1] - t1) * r12 + (out[n, 2] - t2) * r22
    return True


def _sheet_tables(procam: ProCam, pattern: GridPattern, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Chord-plane normals (2, L, K−1, 3) and end-plane normals (2, L, 3) of every line's light sheet."""
    idx = pattern.indices.astype(np.float64)
    L = len(idx)
    other = idx[0] + np.arange((L - 1) * nodes + 1) / nodes  # (K,)
    K = len(other)
    chords = np.zeros((2, L, K - 1, 3))
    ends = np.zeros((2, L, 3))
    for f in (1, 2):
        ii, oo = np.meshgrid(idx, other, indexing="ij")  # (L, K)
        i, j = (ii, oo) if f == 1 else (oo, ii)
        xy = procam.projector.pixels_to_normalised(pattern.junction_uv(i.ravel(), j.ravel())).reshape(L, K, 2)
        rays = np.concatenate([xy, np.ones((L, K, 1))], axis=2)
        n = np.cross(rays[:, :-1], rays[:, 1:])
        chords[f - 1] = n / np.linalg.norm(n, axis=2, keepdims=True)
        e = np.cross(rays[:, 0], rays[:, -1])
        ends[f - 1] = e / np.linalg.norm(e, axis=1, keepdims=True)
    return chords, ends


def _cam_table(procam: ProCam, step: int) -> np.ndarray | None:
    """Normalised undistorted coordinates (th, tw, 2) of camera pixels on a grid `step` px apart, one node
    beyond the image on each far side (so every pixel centre is inside the table)."""
    cam = procam.camera
    if not cam.has_distortion:
        return None
    tw = int(np.ceil((cam.width - 1) / step)) + 2
    th = int(np.ceil((cam.height - 1) / step)) + 2
    gv, gu = np.mgrid[0:th, 0:tw]
    q = np.column_stack([gu.ravel(), gv.ravel()]).astype(np.float64) * step
    return np.ascontiguousarray(cam.pixels_to_normalised(q).reshape(th, tw, 2))


def _reference_depth(procam: ProCam, depth_range_mm: tuple[float, float]) -> float:
    """Depth where the camera's optical axis passes closest to the projector's (the rig's working point)."""
    p, _ = triangulate_rays(procam, np.zeros((1, 2)), np.zeros((1, 2)))
    z = float(p[0, 2])
    lo, hi = depth_range_mm
    if not np.isfinite(z) or z <= 0:
        z = float(np.sqrt(lo * hi))
    return float(np.clip(z, lo, hi))


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
    sheet_normals, sheet_end_normals = _sheet_tables(procam, pattern, _SHEET_NODES)
    cam_xy_table = _cam_table(procam, _CAM_TABLE_PX)
    offsets = np.ascontiguousarray(np.stack([pattern.offsets_px(1), pattern.offsets_px(2)]).astype(np.float64))
    for a in (dir_cam, J_proj_cam, sheet_normals, sheet_end_normals, cam_xy_table, offsets):
        if a is not None:
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
        margin=labelling_margin(procam, pattern, depth_range_mm=depth_range_mm),
        line_offsets_px=offsets,
        cam_table_px=_CAM_TABLE_PX,
        cam_xy_table=cam_xy_table,
        sheet_nodes=_SHEET_NODES,
        sheet_normals=sheet_normals,
        sheet_end_normals=sheet_end_normals,
    )
