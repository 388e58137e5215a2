"""Look-ups in the simulator's ground truth that several reconstruction tests share."""

from __future__ import annotations

import cv2
import numpy as np


def true_index(truth, pattern, q: np.ndarray, fam: np.ndarray) -> np.ndarray:
    """The fractional index of the line of each sample's family (1: i, 2: j) that the truth's projector position
    at camera position q (N, 2) lies on (bilinear in truth.q_proj; NaN off the surface)."""
    if len(q) == 0:
        return np.zeros(0)
    m = q.astype(np.float32).reshape(-1, 1, 2)
    qp = cv2.remap(truth.q_proj.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(-1, 2)
    n = np.where(fam == 1, pattern.n1, pattern.n2)
    return ((qp[:, 1] - pattern.centre_px[1]) - n * (qp[:, 0] - pattern.centre_px[0])) / pattern.pitch_px


def object_at(truth, q: np.ndarray) -> np.ndarray:
    """The scene object index (−1: none) seen at camera position q (N, 2), nearest pixel."""
    if len(q) == 0:
        return np.zeros(0)
    m = q.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(truth.object_id.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_NEAREST).ravel()
