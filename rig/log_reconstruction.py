"""Log one reconstruction result into a Rerun recording (entities: docs/reconstruction.md, docs/recording.md).

    world/camera/depth        DepthImage, camera-frame z in mm (meter = 1000), NaN → 0 (no data)
    world/points              Points3D (float32, world = projector frame, mm), coloured by depth or by label
    world/camera/image/grid   junctions (Points2D, "(i, j)" labels) and segments (LineStrips2D)
    stats/…                   Scalars per frame: junctions found/labelled, points, ambiguous components, ms

The caller selects the frame (`rec.set_time(...)`) before calling.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from reconstruction.pipeline import Reconstruction
from reconstruction.rigmodel import UNLABELLED


def _turbo(x: np.ndarray) -> np.ndarray:
    """Values in [0, 1] -> (N, 3) uint8 colours (OpenCV's TURBO map)."""
    import cv2

    idx = np.clip(np.nan_to_num(x) * 255, 0, 255).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(idx, cv2.COLORMAP_TURBO).reshape(-1, 3)[:, ::-1].copy()


def point_colours(result: Reconstruction, *, by: Literal["depth", "label"] = "depth") -> np.ndarray:
    """(N, 3) uint8 colours of the result's points: by camera depth (near = blue … far = red) or by line label."""
    n = result.n_points
    if n == 0:
        return np.zeros((0, 3), np.uint8)
    if by == "label":
        lab = result.label.astype(np.int64)
        key = np.where(lab[:, 0] != UNLABELLED, lab[:, 0], lab[:, 1] + 1000)
        return _turbo(((key * 0.6180339887) % 1.0))
    # depth of each point: look it up in the depth map at its pixel
    h, w = result.depth_cam.shape
    c = np.clip(np.rint(result.q_cam[:, 0]).astype(np.intp), 0, w - 1)
    r = np.clip(np.rint(result.q_cam[:, 1]).astype(np.intp), 0, h - 1)
    z = result.depth_cam[r, c]
    return _turbo((z - np.nanmin(z)) / max(float(np.nanmax(z) - np.nanmin(z)), 1e-9))


def log_reconstruction(
    rec,
    result: Reconstruction,
    *,
    camera_entity: str = "world/camera",
    points_entity: str = "world/points",
    colour_by: Literal["depth", "label"] = "depth",
    stats_prefix: str = "stats",
) -> None:
    """Log `result` on the recording stream `rec` (rr.RecordingStream) at its current time."""
    import rerun as rr

    depth = np.fmax(result.depth_cam, np.float32(0.0))  # NaN (nothing measured) -> 0, Rerun's "no depth"; one pass
    rec.log(f"{camera_entity}/depth", rr.DepthImage(depth, meter=1000.0))
    rec.log(
        points_entity,
        rr.Points3D(result.points_proj.astype(np.float32), colors=point_colours(result, by=colour_by), radii=rr.Radius.ui_points(1.5)),
    )
    labelled = result.junction_labels[:, 0] != UNLABELLED
    labels = [f"({i}, {j})" if ok else "?" for (i, j), ok in zip(result.junction_labels.tolist(), labelled.tolist())]
    colours = np.where(labelled[:, None], np.array([[60, 220, 60]], np.uint8), np.array([[230, 60, 60]], np.uint8))
    rec.log(
        f"{camera_entity}/image/grid/junctions",
        rr.Points2D(result.junctions_cam.astype(np.float32), labels=labels, colors=colours, radii=rr.Radius.ui_points(2.0), show_labels=False),
    )
    seg_col = np.where(result.segment_labelled[:, None], np.array([[80, 160, 255]], np.uint8), np.array([[160, 160, 160]], np.uint8))
    rec.log(f"{camera_entity}/image/grid/segments", rr.LineStrips2D(np.asarray(result.segments, np.float32), colors=seg_col, radii=rr.Radius.ui_points(0.75)))
    s = result.stats
    scalars = {
        "junctions_found": s.get("junctions_found", 0),
        "junctions_labelled": s.get("junctions_labelled", 0),
        "points": s.get("points", 0),
        "ambiguous_components": s.get("ambiguous", 0),
    }
    for k, v in s.get("ms", {}).items():
        scalars[f"ms/{k}"] = v
    for k, v in scalars.items():
        rec.log(f"{stats_prefix}/{k}", rr.Scalars(float(v)))
