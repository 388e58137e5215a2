"""The dense multi-shot mode: Gray-code columns and rows (with inverses) in, a per-pixel range map out.

    patterns = graycode_scan_patterns(projector_width, projector_height)    # project these, in order
    result = reconstruct_graycode(images, procam)                          # one camera image per pattern

Every camera pixel whose Gray code decodes (calibration.graycode.decode_graycode: black subtracted, direct and
global light separated, each bit decided against its inverse, 3x3 consistency) gets the projector pixel (u, v)
that lit it. It is then triangulated either as the closest approach of its camera ray and the projector ray
through (u, v) ("rays"), or as its camera ray meeting the light plane of projector column u or row v ("planes":
the family that crosses the epipolar lines, i.e. columns when the camera sits mostly beside the projector and
rows when it sits mostly above or below; the other coordinate only serves as a consistency check). Distortion of both devices is removed at the boundary, as in the
grid pipeline. The result is the grid pipeline's `Reconstruction`, so recording (rig.log_reconstruction), PLY
and depth outputs work unchanged; its grid fields are empty.

The decoded (u, v) are whole projector pixels (the centre of the pixel that lit the camera pixel), a
quantisation of ±½ projector pixel; the scene must not move during the 2·(⌈log2 W⌉ + ⌈log2 H⌉) + 2 frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from calibration.errors import CalibrationError, ReconstructionError
from calibration.graycode import decode_graycode, graycode_pattern_count, graycode_patterns
from calibration.models import Intrinsics, ProCam
from reconstruction.geometry import depth_cam as depth_cam_of
from reconstruction.geometry import intersect_planes, triangulate_rays
from reconstruction.pipeline import Reconstruction


@dataclass(frozen=True)
class GrayCodeOptions:
    """method: "rays" (camera ray ↔ projector ray through the decoded (u, v), midpoint) or "planes" (camera
    ray ∩ light plane of the decoded column u, or row v when the camera is mostly above or below the
    projector: `plane_family`). depth_min_mm, depth_max_mm: the working volume (camera-frame
    z); points outside are dropped. max_residual_px: points whose reprojection into the projector is
    farther than this from the decoded (u, v) are dropped (a wrong row or column bit). min_direct: the
    decoder's direct-light threshold in 8-bit grey levels (None: automatic)."""

    method: Literal["rays", "planes"] = "rays"
    depth_min_mm: float = 100.0
    depth_max_mm: float = 10000.0
    max_residual_px: float = 1.5
    min_direct: float | None = None

    def __post_init__(self) -> None:
        if self.method not in ("rays", "planes"):
            raise ValueError(f"method must be 'rays' or 'planes', got {self.method!r}")
        if not 0 < self.depth_min_mm < self.depth_max_mm:
            raise ValueError(f"need 0 < depth_min_mm < depth_max_mm, got {self.depth_min_mm}, {self.depth_max_mm}")
        if not self.max_residual_px > 0:
            raise ValueError(f"max_residual_px must be > 0, got {self.max_residual_px}")


def graycode_scan_patterns(projector_width: int, projector_height: int) -> list[np.ndarray]:
    """The projector images of one Gray-code scan, (projector_height, projector_width) uint8 each.

    OpenCV's GrayCodePattern order: for each column bit (most significant first) the pattern and its
    inverse, then the row bits the same way, then white and black: 2·(⌈log2 W⌉ + ⌈log2 H⌉) + 2 images
    (42 for 1024×768 or 1024×1024).
    """
    return graycode_patterns(projector_width, projector_height)


def graycode_frame_count(projector_width: int, projector_height: int) -> int:
    """How many frames one Gray-code scan takes for this projector (len(graycode_scan_patterns(...)))."""
    return graycode_pattern_count(projector_width, projector_height)


def plane_family(procam: ProCam) -> Literal["columns", "rows"]:
    """Which projector lines make the better light planes: the family crossing the epipolar lines.

    The epipolar line through the projector's optical axis runs along (t_x, t_y) (t = camera centre in the
    projector frame); columns cross it best when |t_x| >= |t_y|, rows otherwise.
    """
    tx, ty, _ = procam.t_proj_cam
    return "columns" if abs(tx) >= abs(ty) else "rows"


def light_plane_normals(
    projector: Intrinsics, q_proj: np.ndarray, *, family: Literal["columns", "rows"], half_span_px: float = 2.0
) -> np.ndarray:
    """Normals (N, 3) of the light planes of the projector columns (or rows) at pixels q_proj (N, 2).

    The plane of column u at (u, v) passes through the projector centre and the rays of (u, v ± half_span_px)
    (rows: (u ± half_span_px, v)). Without distortion this is the whole column's plane; with distortion a
    column's light is a curved surface and this is its tangent plane where the decoded pixel lies.
    """
    q = np.asarray(q_proj, dtype=np.float64).reshape(-1, 2)
    step = np.array([0.0, half_span_px]) if family == "columns" else np.array([half_span_px, 0.0])
    rays = projector.rays(np.concatenate([q - step, q + step]))
    return np.cross(rays[: len(q)], rays[len(q) :])


def reconstruct_graycode(
    images: Sequence[np.ndarray], procam: ProCam, *, options: GrayCodeOptions = GrayCodeOptions()
) -> Reconstruction:
    """Decode one Gray-code scan (images in `graycode_scan_patterns` order) into points and a range map.

    images: the camera frames, (H, W) uint8/uint16 (or BGR) at the calibration's camera size, one per
    pattern. Returns a Reconstruction whose points are the decoded camera pixels: points_proj (N, 3)
    world (projector) frame mm, q_cam (N, 2) their camera pixels, family 0, label (N, 2) the decoded
    projector pixel (u, v), residual (N,) the reprojection distance in projector px, depth_cam (H, W) with a
    value at every such pixel. Grid fields (junctions, segments) are empty. stats: decoded, points,
    dropped counts, ms per stage. Raises ReconstructionError when the frames do not fit the calibration.
    """
    t0 = time.perf_counter()
    cam, proj = procam.camera, procam.projector
    expected = graycode_frame_count(proj.width, proj.height)
    if len(images) != expected:
        raise ReconstructionError(
            f"a Gray-code scan of the {proj.width}x{proj.height} projector has {expected} frames, got {len(images)}: "
            "capture every pattern of graycode_scan_patterns() in order"
        )
    for k, im in enumerate(images):
        h, w = np.asarray(im).shape[:2]
        if (w, h) != (cam.width, cam.height):
            raise ReconstructionError(
                f"Gray-code frame {k} is {w}x{h} but the calibration's camera is {cam.width}x{cam.height}; "
                "use the calibration made for this camera mode"
            )
    try:
        dec = decode_graycode(
            images, projector_width=proj.width, projector_height=proj.height, min_direct=options.min_direct
        )
    except CalibrationError as e:  # same message, the reconstruction's error class
        raise ReconstructionError(str(e)) from e
    t_decode = time.perf_counter()

    vv, uu = np.nonzero(dec.valid)
    q_cam = np.column_stack([uu, vv]).astype(np.float64)
    q_proj = np.column_stack([dec.u_proj[vv, uu], dec.v_proj[vv, uu]]).astype(np.float64)
    xy_cam = cam.pixels_to_normalised(q_cam)
    if options.method == "rays":
        p_proj, _gap = triangulate_rays(procam, xy_cam, proj.pixels_to_normalised(q_proj))
    else:
        family = plane_family(procam)
        # One plane per decoded projector pixel (not per column): with distortion a column is not a plane.
        key, inverse = np.unique(q_proj[:, 1] * proj.width + q_proj[:, 0], return_inverse=True)
        q_unique = np.column_stack([key % proj.width, key // proj.width])
        normals = light_plane_normals(proj, q_unique, family=family)[inverse.reshape(-1)]
        p_proj = intersect_planes(procam, xy_cam, normals)
    t_tri = time.perf_counter()

    z = depth_cam_of(procam, p_proj)
    with np.errstate(invalid="ignore"):
        residual = np.linalg.norm(proj.project(p_proj) - q_proj, axis=1)
        in_range = (z >= options.depth_min_mm) & (z <= options.depth_max_mm)
        consistent = residual <= options.max_residual_px
    keep = np.all(np.isfinite(p_proj), axis=1) & in_range & consistent
    depth = np.full((cam.height, cam.width), np.nan, np.float32)
    depth[vv[keep], uu[keep]] = z[keep]
    t_end = time.perf_counter()

    n_dec, n_keep = int(len(q_cam)), int(keep.sum())
    stats = {
        "pixels": int(cam.width * cam.height),
        "decoded": n_dec,
        "points": n_keep,
        "dropped_depth": int((~in_range & np.isfinite(z)).sum()),
        "dropped_residual": int((in_range & ~consistent).sum()),
        "min_direct": float(dec.min_direct),
        "ms": {
            "decode": 1e3 * (t_decode - t0),
            "triangulate": 1e3 * (t_tri - t_decode),
            "filter": 1e3 * (t_end - t_tri),
            "total": 1e3 * (t_end - t0),
        },
    }
    warnings = []
    if n_keep == 0:
        warnings.append(
            "no camera pixel decoded to a point: check that the projector lights the scene, the frames are in "
            "pattern order and each was exposed after its pattern was shown"
        )
    elif n_keep < 0.5 * n_dec:
        warnings.append(
            f"only {n_keep} of {n_dec} decoded pixels triangulated consistently: the calibration may not match the rig"
        )
    return Reconstruction(
        points_proj=p_proj[keep].astype(np.float32),
        q_cam=q_cam[keep].astype(np.float32),
        family=np.zeros(n_keep, np.int8),
        label=q_proj[keep].astype(np.int32),
        residual=residual[keep].astype(np.float32),
        depth_cam=depth,
        junctions_cam=np.zeros((0, 2), np.float32),
        junction_labels=np.zeros((0, 2), np.int32),
        segments=np.zeros((0, 2, 2), np.float32),
        segment_labelled=np.zeros(0, bool),
        stats=stats,
        warnings=warnings,
    )
