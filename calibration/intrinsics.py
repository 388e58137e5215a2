"""Intrinsics of one device (camera, or projector used backwards) from several views of a planar board.

Pure functions on arrays. Inputs are, per view, the board corners in the board frame (N, 3) mm and their
pixels in the device's image (N, 2); outputs are an `Intrinsics` plus the diagnostics users need to trust
it: RMS, per-view RMS, parameter standard deviations, outlier views, coverage of the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np

from calibration.errors import CalibrationError
from calibration.models import Intrinsics
from calibration.report import coverage_fraction

#: names of calibrateCameraExtended's stdDeviationsIntrinsics entries, in its order.
STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")

MIN_VIEWS = 3


@dataclass(frozen=True, eq=False)
class IntrinsicsResult:
    """One device's calibration.

    intrinsics: the model. rms_px: RMS reprojection error over all corners of the used views.
    per_view_rms_px: (V,) in the order of `names`. std: {parameter: standard deviation} (pixels for
    fx…cy, unitless for distortion), only the estimated ones. rvecs, tvecs: (V, 3) board -> device
    (Rodrigues, mm). residuals_px: per view (N, 2) observed minus reprojected. outliers: names of used views
    whose error stands out (see `find_outliers`). rejected: names of views dropped by reject_outliers.
    coverage: fraction of the image covered by the boards' convex hulls.
    """

    intrinsics: Intrinsics
    rms_px: float
    per_view_rms_px: np.ndarray
    std: dict
    rvecs: np.ndarray
    tvecs: np.ndarray
    residuals_px: list
    names: tuple
    outliers: tuple = ()
    rejected: tuple = ()
    coverage: float = 0.0
    flags: int = 0
    extra: dict = field(default_factory=dict)

    def quality(self) -> dict:
        """The JSON-ready summary stored in a calibration file's `quality`."""
        return {
            "rms_px": round(self.rms_px, 4),
            "views": len(self.names),
            "per_view_rms_px": {n: round(float(e), 4) for n, e in zip(self.names, self.per_view_rms_px)},
            "std": {k: float(f"{v:.4g}") for k, v in self.std.items()},
            "outlier_views": list(self.outliers),
            "rejected_views": list(self.rejected),
            "coverage": round(self.coverage, 3),
        }


def find_outliers(per_view_rms_px: np.ndarray, *, factor: float = 3.0, floor_px: float = 0.1) -> np.ndarray:
    """Indices of views whose RMS exceeds `factor` x the median view RMS and `floor_px`.

    The floor keeps noise-level differences between very clean views (simulated data) from being flagged.
    """
    e = np.asarray(per_view_rms_px, dtype=np.float64)
    if e.size < MIN_VIEWS:
        return np.zeros(0, dtype=int)
    return np.flatnonzero((e > factor * np.median(e)) & (e > floor_px))


def _board_normals(object_points_mm: Sequence[np.ndarray], q_px: Sequence[np.ndarray], *, width: int, height: int) -> np.ndarray:
    """Rough board normals (V, 3) in the device frame from each view's homography and a guessed K.

    Only used to detect degenerate sets of poses (all boards parallel), so a guessed focal length is enough.
    """
    f = float(max(width, height))
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    Kinv = np.linalg.inv(K)
    normals = []
    for P, q in zip(object_points_mm, q_px):
        H, _ = cv2.findHomography(P[:, :2].astype(np.float64), q.astype(np.float64), 0)
        if H is None:
            normals.append([0.0, 0.0, 1.0])
            continue
        M = Kinv @ H
        r1, r2 = M[:, 0] / np.linalg.norm(M[:, 0]), M[:, 1] / np.linalg.norm(M[:, 1])
        n = np.cross(r1, r2)
        normals.append(n / np.linalg.norm(n) * np.sign(n[2] or 1.0))
    return np.asarray(normals)


def check_pose_diversity(
    object_points_mm: Sequence[np.ndarray], q_px: Sequence[np.ndarray], *, width: int, height: int, min_angle_deg: float = 5.0, device: str = "camera"
) -> float:
    """Largest angle (degrees) between any two board orientations; CalibrationError below `min_angle_deg`.

    With every board parallel (pure translations) focal length and distance cannot be told apart.
    """
    n = _board_normals(object_points_mm, q_px, width=width, height=height)
    cos = np.clip(n @ n.T, -1.0, 1.0)
    spread = float(np.degrees(np.arccos(cos.min())))
    if spread < min_angle_deg:
        raise CalibrationError(
            f"degenerate board poses for the {device}: all {len(n)} views show the board at the same orientation "
            f"(largest difference {spread:.1f} deg); capture views with the board tilted 20-45 deg "
            "left/right and up/down, not only moved"
        )
    return spread


def calibrate_intrinsics(
    object_points_mm: Sequence[np.ndarray],
    q_px: Sequence[np.ndarray],
    *,
    width: int,
    height: int,
    names: Sequence[str] | None = None,
    flags: int = 0,
    K_guess: np.ndarray | None = None,
    reject_outliers: bool = False,
    outlier_factor: float = 3.0,
    device: str = "camera",
    min_corners: int = 6,
) -> IntrinsicsResult:
    """Calibrate one device (OpenCV's calibrateCameraExtended, model [k1, k2, p1, p2, k3] unless `flags` say).

    object_points_mm: per view (N_i, 3) board-frame corners, z = 0. q_px: per view (N_i, 2) pixels.
    width, height: the image size in pixels. flags: cv2.CALIB_* (e.g. CALIB_FIX_K3 with few views).
    reject_outliers: drop the views `find_outliers` flags and solve again, until none is flagged
    (never below 3 views). Raises CalibrationError for too few views or corners, or degenerate poses.
    """
    P = [np.asarray(p, np.float64).reshape(-1, 3) for p in object_points_mm]
    Q = [np.asarray(q, np.float64).reshape(-1, 2) for q in q_px]
    names = tuple(names) if names is not None else tuple(f"view{i}" for i in range(len(P)))
    if len(P) != len(Q) or len(P) != len(names):
        raise ValueError("object_points_mm, q_px and names must have one entry per view")
    keep = [i for i in range(len(P)) if len(P[i]) >= min_corners and len(P[i]) == len(Q[i])]
    if len(keep) < MIN_VIEWS:
        raise CalibrationError(
            f"too few usable views for the {device}: {len(keep)} with the board found (need at least {MIN_VIEWS}, "
            "better 8-15); capture more views with the whole board visible, tilted in different directions"
        )
    P, Q, names = [P[i] for i in keep], [Q[i] for i in keep], tuple(names[i] for i in keep)
    check_pose_diversity(P, Q, width=width, height=height, device=device)

    rejected: list[str] = []
    while True:
        res = _solve(P, Q, names, width=width, height=height, flags=flags, K_guess=K_guess)
        bad = find_outliers(res.per_view_rms_px, factor=outlier_factor)
        if not reject_outliers or len(bad) == 0 or len(P) - len(bad) < MIN_VIEWS:
            break
        rejected += [names[i] for i in bad]
        good = [i for i in range(len(P)) if i not in set(bad.tolist())]
        P, Q, names = [P[i] for i in good], [Q[i] for i in good], tuple(names[i] for i in good)
    outliers = tuple(names[i] for i in find_outliers(res.per_view_rms_px, factor=outlier_factor))
    _check_determined(res, device=device)
    return IntrinsicsResult(
        intrinsics=res.intrinsics,
        rms_px=res.rms_px,
        per_view_rms_px=res.per_view_rms_px,
        std=res.std,
        rvecs=res.rvecs,
        tvecs=res.tvecs,
        residuals_px=res.residuals_px,
        names=names,
        outliers=outliers,
        rejected=tuple(rejected),
        coverage=coverage_fraction(Q, width=width, height=height),
        flags=flags,
    )


def _solve(P, Q, names, *, width, height, flags, K_guess) -> IntrinsicsResult:
    K0 = None if K_guess is None else np.asarray(K_guess, np.float64).copy()
    if K0 is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    try:
        rms, K, dist, rvecs, tvecs, std_i, _std_e, per_view = cv2.calibrateCameraExtended(
            [p.astype(np.float32) for p in P],
            [q.astype(np.float32).reshape(-1, 1, 2) for q in Q],
            (width, height),  # OpenCV's imageSize is (W, H)
            K0,
            None,
            flags=flags,
            criteria=crit,
        )
    except cv2.error as e:
        raise CalibrationError(
            f"OpenCV could not calibrate from these {len(P)} views ({e.err}); capture more views with the board tilted in different directions"
        ) from e
    dist = np.asarray(dist, np.float64).ravel()
    dist = dist[:5] if not np.any(dist[5:]) else dist
    intr = Intrinsics(width, height, K, dist)
    std_i = np.asarray(std_i, np.float64).ravel()
    estimated = _estimated(flags, len(dist))
    std = {n: float(s) for n, s in zip(STD_NAMES, std_i) if n in estimated}
    rv = np.asarray(rvecs, np.float64).reshape(-1, 3)
    tv = np.asarray(tvecs, np.float64).reshape(-1, 3)
    residuals = []
    for p, q, r, t in zip(P, Q, rv, tv):
        proj = cv2.projectPoints(p, r, t, K, dist)[0].reshape(-1, 2)
        residuals.append(q - proj)
    return IntrinsicsResult(intr, float(rms), np.asarray(per_view, np.float64).ravel(), std, rv, tv, residuals, names, flags=flags)


def _estimated(flags: int, n_dist: int) -> set:
    out = {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}
    if flags & cv2.CALIB_FIX_PRINCIPAL_POINT:
        out -= {"cx", "cy"}
    if flags & cv2.CALIB_ZERO_TANGENT_DIST:
        out -= {"p1", "p2"}
    for k, fl in (("k1", cv2.CALIB_FIX_K1), ("k2", cv2.CALIB_FIX_K2), ("k3", cv2.CALIB_FIX_K3)):
        if flags & fl:
            out.discard(k)
    if flags & cv2.CALIB_RATIONAL_MODEL:
        out |= {"k4", "k5", "k6"}
    return out


def _check_determined(res: IntrinsicsResult, *, device: str) -> None:
    """The solve ran but focal length or principal point are barely determined: say which poses to add."""
    K = res.intrinsics
    rel_f = max(res.std.get("fx", 0.0) / K.fx, res.std.get("fy", 0.0) / K.fy)
    if not np.isfinite(rel_f) or rel_f > 0.05:
        raise CalibrationError(
            f"the {device}'s focal length is undetermined by these views (uncertainty {100 * rel_f:.0f} %): "
            "the poses are too similar; add views with the board tilted 20-45 deg in different directions"
        )


def board_view_arrays(views, board) -> tuple[list[np.ndarray], list[np.ndarray], list[str]]:
    """BoardViews -> (object points per view (N, 3) mm, pixels per view (N, 2), names)."""
    return [v.object_points_mm(board) for v in views], [v.q_cam for v in views], [v.source for v in views]


def check_same_size(sizes: Sequence[tuple[int, int]], names: Sequence[str], *, device: str = "camera") -> tuple[int, int]:
    """(width, height) shared by all images; CalibrationError naming the first odd one out."""
    w, h = sizes[0]
    for (wi, hi), n in zip(sizes, names):
        if (wi, hi) != (w, h):
            raise CalibrationError(
                f"{n}: {device} image is {wi}x{hi} but {names[0]} is {w}x{h}; every view must come from the same "
                "camera at the same resolution (capture them again with one setting)"
            )
    return w, h
