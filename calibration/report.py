"""Diagnostics shared by the camera and projector calibrations: image coverage, the verdict text.

Pure functions; no OpenCV calibration here (only polygon filling for coverage masks).
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

#: cells per image side used for coverage masks (the longer side); enough to see "the top-left corner is empty".
COVERAGE_CELLS = 48

#: below these a calibration is called "not enough" in the verdict.
GOOD_COVERAGE = 0.5
GOOD_VIEWS = 8

_REGIONS = (("top", "left"), ("top", "centre"), ("top", "right"), ("middle", "left"), ("middle", "centre"), ("middle", "right"),
            ("bottom", "left"), ("bottom", "centre"), ("bottom", "right"))


def coverage_mask(q_px: Sequence[np.ndarray], *, width: int, height: int, cells: int = COVERAGE_CELLS) -> np.ndarray:
    """Boolean (rows, cols) mask of the image cells inside the convex hull of at least one view's points.

    q_px: per view (N, 2) pixels. The grid has `cells` cells along the longer side.
    """
    scale = cells / max(width, height)
    shape = (max(1, round(height * scale)), max(1, round(width * scale)))
    mask = np.zeros(shape, np.uint8)
    for q in q_px:
        q = np.asarray(q, np.float64).reshape(-1, 2)
        q = q[np.all(np.isfinite(q), axis=1)]
        if len(q) < 3:
            continue
        hull = cv2.convexHull(((q + 0.5) * scale).astype(np.float32))
        cv2.fillConvexPoly(mask, np.round(hull).astype(np.int32), 1)
    return mask.astype(bool)


def coverage_fraction(q_px: Sequence[np.ndarray], *, width: int, height: int) -> float:
    """Fraction (0..1) of the image covered by the union of the views' convex hulls."""
    return float(coverage_mask(q_px, width=width, height=height).mean())


def empty_regions(q_px: Sequence[np.ndarray], *, width: int, height: int, min_fraction: float = 0.3) -> list[str]:
    """Names ("top left", …) of the image's ninths covered less than `min_fraction`: where to put the board next."""
    m = coverage_mask(q_px, width=width, height=height)
    rows = np.array_split(np.arange(m.shape[0]), 3)
    cols = np.array_split(np.arange(m.shape[1]), 3)
    out = []
    for k, (r, c) in enumerate((r, c) for r in rows for c in cols):
        if m[np.ix_(r, c)].mean() < min_fraction:
            v, h = _REGIONS[k]
            out.append("centre" if (v, h) == ("middle", "centre") else f"{v} {h}")
    return out


def verdict(quality: dict) -> list[str]:
    """Short human verdict lines from a procam or camera `quality` dict (the calibration file's).

    Recognised keys: camera / projector (each with rms_px, views, coverage, outlier_views, empty_regions),
    stereo_rms_px, baseline_mm.
    """
    lines = []
    advice = []
    for dev in ("camera", "projector"):
        q = quality.get(dev)
        if not q:
            continue
        lines.append(
            f"{dev}: RMS {q['rms_px']:.3f} px over {q['views']} views, coverage {100 * q['coverage']:.0f} %"
            + (f", outlier views: {', '.join(q['outlier_views'])}" if q.get("outlier_views") else "")
        )
        if q.get("outlier_views"):
            advice.append(f"check or drop the {dev}'s outlier views ({', '.join(q['outlier_views'])}; --reject-outliers)")
        if q["coverage"] < GOOD_COVERAGE and q.get("empty_regions"):
            advice.append(f"add poses with the board in the {dev} image's {', '.join(q['empty_regions'][:3])}")
    if "stereo_rms_px" in quality:
        lines.append(f"stereo: RMS {quality['stereo_rms_px']:.3f} px, baseline {quality.get('baseline_mm', float('nan')):.1f} mm")
    n_views = min((quality[d]["views"] for d in ("camera", "projector") if quality.get(d)), default=0)
    if n_views < GOOD_VIEWS:
        advice.insert(0, f"only {n_views} views: {GOOD_VIEWS}-15 give stable results; add tilted poses")
    if advice:
        lines.append("verdict: usable, but " + "; ".join(advice))
    else:
        lines.append("verdict: good: enough views, good coverage, no outliers")
    return lines
