"""Look-ups in the simulator's ground truth, and the junction graph it implies, that several reconstruction tests share."""

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


def lattice_edges(labels: np.ndarray, joined=None) -> tuple[np.ndarray, np.ndarray]:
    """The junction graph a perfect extraction would give junctions with these true labels (N, 2): an edge k → o with
    step (1, 0) or (0, 1) wherever junction o is junction k's neighbour in i or j, in the order of k then the step;
    joined(k, o): keep only the edges it accepts (e.g. within one surface). (edges (E, 2), delta (E, 2)) int64."""
    key = {tuple(v): k for k, v in enumerate(np.asarray(labels).tolist())}
    edges, delta = [], []
    for k, (i, j) in enumerate(np.asarray(labels).tolist()):
        for d in ((1, 0), (0, 1)):
            o = key.get((i + d[0], j + d[1]))
            if o is not None and (joined is None or joined(k, o)):
                edges.append((k, o))
                delta.append(d)
    return np.array(edges, np.int64).reshape(-1, 2), np.array(delta, np.int64).reshape(-1, 2)
