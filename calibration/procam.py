"""Projector–camera calibration from board poses captured under Gray code (Moreno & Taubin 2012).

Per pose: decode the Gray code (calibration.graycode), find the board in the white image, and give each
board corner its projector coordinates through a homography fitted to the decoded pixels around it (a
"local homography": exact for a plane, insensitive to the camera's and projector's lens distortion at
that scale). Then calibrate the camera and the projector like two cameras (the projector's principal
point is free: projectors have lens shift) and find R, t with OpenCV's stereoCalibrate.

Convention (CONVENTIONS.md): p_proj = R_proj_cam · p_cam + t_proj_cam. stereoCalibrate with the camera as
device 1 and the projector as device 2 returns R, T with p2 = R · p1 + T, which is already ours.
Translations come out in the board's unit (`square_mm`).

Pose directories: either our own recordings (manifest.json with frames [{"file", "pattern"}], pattern ids
indexing the Gray-code sequence; frames.jsonl is read when the manifest lists none), or any folder holding
exactly the Gray-code images in OpenCV's order, sorted by name (numbers inside names compared as numbers).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from calibration.boards import Board, BoardView, detect_board, read_image
from calibration.errors import CalibrationError
from calibration.file import CalibrationFile
from calibration.graycode import GrayCodeDecoding, check_decodes, decode_graycode, graycode_pattern_count
from calibration.intrinsics import MIN_VIEWS, IntrinsicsResult, calibrate_intrinsics, check_same_size
from calibration.models import Intrinsics, ProCam
from calibration.report import empty_regions

#: from this many poses on, the stereo solve refines the intrinsics jointly by default (decision 0061).
JOINT_MIN_VIEWS = 8

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm")


# --- reading pose directories -----------------------------------------------------------------------------------


def _natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def pose_image_paths(pose_dir: str | os.PathLike, *, n_patterns: int) -> list[Path]:
    """The `n_patterns` image files of one pose, in Gray-code order. CalibrationError if they are not all there."""
    d = Path(pose_dir)
    if not d.is_dir():
        raise CalibrationError(f"{d}: not a directory (each pose is a folder of Gray-code captures)")
    manifest = d / "manifest.json"
    if manifest.exists():
        try:
            data = json.loads(manifest.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, OSError) as e:
            raise CalibrationError(f"{manifest}: unreadable ({e}); the capture is damaged, record this pose again") from e
        frames = data.get("frames") or []
        jsonl = d / "frames.jsonl"
        if not frames and jsonl.exists():
            frames = [json.loads(line) for line in jsonl.read_text(encoding="utf-8").splitlines() if line.strip()]
        by_pattern: dict[int, Path] = {}
        for f in frames:
            by_pattern.setdefault(int(f["pattern"]), d / f["file"])  # first frame of each pattern
        missing = [i for i in range(n_patterns) if i not in by_pattern]
        if missing:
            raise CalibrationError(
                f"{manifest}: lists frames for {len(by_pattern)} patterns, the Gray code needs {n_patterns} "
                f"(missing pattern ids {missing[:6]}{'…' if len(missing) > 6 else ''}); record this pose again"
            )
        return [by_pattern[i] for i in range(n_patterns)]
    files = sorted((p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: _natural_key(p.name))
    if len(files) != n_patterns:
        raise CalibrationError(
            f"{d}: holds {len(files)} images, a Gray code for this projector size needs {n_patterns} "
            "(OpenCV GrayCodePattern order: each bit's pattern then its inverse, columns then rows, then white and black); "
            "check --projector-size, or capture the pose again"
        )
    return files


# --- per pose ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ProcamView:
    """One board pose seen by both devices.

    ids: (N,) board corner ids found in the camera. q_cam: (N, 2) camera pixels. q_proj: (N, 2) projector
    pixels (NaN where the local homography had too few decoded pixels). samples: (N,) decoded pixels used
    per corner. valid_fraction: the share of camera pixels whose Gray code decoded.
    """

    name: str
    ids: np.ndarray
    q_cam: np.ndarray
    q_proj: np.ndarray
    samples: np.ndarray
    camera_width: int
    camera_height: int
    valid_fraction: float

    @property
    def projector_ok(self) -> np.ndarray:
        return np.all(np.isfinite(self.q_proj), axis=1)


def local_homography_corners(
    dec: GrayCodeDecoding, q_cam: np.ndarray, *, half_window_px: int, min_samples: int = 30, ransac_px: float = 1.5
) -> tuple[np.ndarray, np.ndarray]:
    """Projector coordinates (N, 2) of camera points q_cam (N, 2) by local homographies (Moreno & Taubin).

    Around each point, every valid decoded camera pixel within `half_window_px` (a square window) gives a
    correspondence (u, v)_cam -> (u_proj, v_proj); a homography fitted to them (RANSAC, then least squares
    on the inliers) maps the point itself. Returns (q_proj, samples); q_proj is NaN where fewer than
    `min_samples` pixels decoded.
    """
    h, w = dec.valid.shape
    q_proj = np.full((len(q_cam), 2), np.nan)
    samples = np.zeros(len(q_cam), np.int64)
    for i, (u, v) in enumerate(np.asarray(q_cam, np.float64)):
        u0, u1 = max(0, int(round(u)) - half_window_px), min(w, int(round(u)) + half_window_px + 1)
        v0, v1 = max(0, int(round(v)) - half_window_px), min(h, int(round(v)) + half_window_px + 1)
        ok = dec.valid[v0:v1, u0:u1]
        n = int(ok.sum())
        samples[i] = n
        if n < min_samples:
            continue
        vv, uu = np.nonzero(ok)
        src = np.column_stack([uu + u0, vv + v0]).astype(np.float64)
        dst = np.column_stack([dec.u_proj[v0:v1, u0:u1][ok], dec.v_proj[v0:v1, u0:u1][ok]]).astype(np.float64)
        # Centre the camera coordinates on the corner: better conditioned and the answer is H applied to 0.
        H, inl = cv2.findHomography(src - (u, v), dst, cv2.RANSAC, ransac_px)
        if H is None or abs(H[2, 2]) < 1e-12:
            continue
        q_proj[i] = H[:2, 2] / H[2, 2]
        samples[i] = int(inl.sum()) if inl is not None else n
    return q_proj, samples


def _corner_spacing_px(view: BoardView) -> float:
    q = view.q_cam
    d = np.linalg.norm(q[:, None, :] - q[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def process_pose(
    images: Sequence[np.ndarray],
    *,
    board: Board,
    projector_width: int,
    projector_height: int,
    name: str,
    half_window_px: int | None = None,
) -> ProcamView:
    """Decode one pose's Gray code, find the board in its white image, and give each corner its projector pixel.

    images: the pose's camera images in Gray-code order. half_window_px: the local homography's window
    (None: half the board's square size in the camera image). CalibrationError if the code does not decode
    or the board is not found.
    """
    dec = decode_graycode(images, projector_width=projector_width, projector_height=projector_height)
    check_decodes(dec, name=name)
    white = images[-2]
    view = detect_board(white, board=board, source=name)
    if view is None:
        raise CalibrationError(
            f"{name}: the board was not found in the white image; check the board options (INNER corners), "
            "that the whole board is in view and lit by the projector, and that the camera is not saturated"
        )
    hw = half_window_px or int(np.clip(round(0.5 * _corner_spacing_px(view)), 8, 80))
    q_proj, samples = local_homography_corners(dec, view.q_cam, half_window_px=hw)
    return ProcamView(name, view.ids, view.q_cam, q_proj, samples, view.width, view.height, dec.valid_fraction)


def load_pose(pose_dir, *, board: Board, projector_width: int, projector_height: int) -> ProcamView:
    """Read one pose directory (see module doc) and process it."""
    paths = pose_image_paths(pose_dir, n_patterns=graycode_pattern_count(projector_width, projector_height))
    images = [read_image(p) for p in paths]
    check_same_size([(im.shape[1], im.shape[0]) for im in images], [p.name for p in paths])
    return process_pose(images, board=board, projector_width=projector_width, projector_height=projector_height, name=Path(pose_dir).name)


# --- the joint solve ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ProcamResult:
    """procam: the calibrated pair. camera, projector: the separate intrinsics solves (RMS, per-view errors,
    standard deviations, coverage). stereo_rms_px: RMS of the joint solve over both images.
    stereo_per_view_rms_px: (V, 2) per view, (camera, projector). views: the poses used."""

    procam: ProCam
    camera: IntrinsicsResult
    projector: IntrinsicsResult
    stereo_rms_px: float
    stereo_per_view_rms_px: np.ndarray
    views: tuple
    notes: list = field(default_factory=list)
    joint: bool = False

    @property
    def rotation_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(cv2.Rodrigues(self.procam.R_proj_cam)[0])))

    def quality(self) -> dict:
        cam_q = self.camera.quality()
        proj_q = self.projector.quality()
        cw, ch = self.procam.camera.width, self.procam.camera.height
        pw, ph = self.procam.projector.width, self.procam.projector.height
        cam_q["empty_regions"] = empty_regions([v.q_cam for v in self.views], width=cw, height=ch)
        proj_q["empty_regions"] = empty_regions([v.q_proj[v.projector_ok] for v in self.views], width=pw, height=ph)
        names = [v.name for v in self.views]
        return {
            "camera": cam_q,
            "projector": proj_q,
            "stereo_rms_px": round(self.stereo_rms_px, 4),
            "stereo_per_view_rms_px": {n: [round(float(a), 4), round(float(b), 4)] for n, (a, b) in zip(names, self.stereo_per_view_rms_px)},
            "baseline_mm": round(self.procam.baseline_mm, 3),
            "rotation_deg": round(self.rotation_deg, 4),
            "corners_per_view": {v.name: int(v.projector_ok.sum()) for v in self.views},
            "graycode_valid_fraction": {v.name: round(v.valid_fraction, 3) for v in self.views},
            "notes": list(self.notes),
        }


def calibrate_procam(
    views: Sequence[ProcamView],
    *,
    board: Board,
    projector_width: int,
    projector_height: int,
    camera: Intrinsics | None = None,
    camera_flags: int = 0,
    projector_flags: int = 0,
    joint: bool | None = None,
) -> ProcamResult:
    """Camera and projector intrinsics and R_proj_cam, t_proj_cam (board units) from processed poses.

    Each device's intrinsics come from its own views (the projector's principal point is free); the
    stereo solve then finds R, t with both fixed. joint=True lets the stereo solve refine every
    intrinsic parameter too; None (default) does so from JOINT_MIN_VIEWS poses on
    (docs/decisions/0061-procam-stereo-fix-intrinsics.md).
    camera: known camera intrinsics (then only the projector and the pose are solved). Flags are
    cv2.CALIB_* for the separate intrinsics solves (e.g. CALIB_FIX_K3 with few poses). CalibrationError
    for too few poses, inconsistent camera sizes or degenerate poses.
    """
    if len(views) < MIN_VIEWS:
        raise CalibrationError(
            f"too few board poses: {len(views)} (need at least {MIN_VIEWS}, better 8-15); capture more poses, "
            "the board tilted 20-45 deg in different directions and placed across the whole projection"
        )
    cw, ch = check_same_size([(v.camera_width, v.camera_height) for v in views], [v.name for v in views])
    names = [v.name for v in views]
    P_cam = [board.object_points_mm[v.ids] for v in views]
    Q_cam = [v.q_cam for v in views]
    P_both = [board.object_points_mm[v.ids[v.projector_ok]] for v in views]
    Q_cam_both = [v.q_cam[v.projector_ok] for v in views]
    Q_proj = [v.q_proj[v.projector_ok] for v in views]
    notes = []
    for v in views:
        if v.projector_ok.sum() < len(v.ids):
            notes.append(f"{v.name}: {len(v.ids) - int(v.projector_ok.sum())} of {len(v.ids)} corners had too few decoded pixels around them")

    if camera is None:
        cam_res = calibrate_intrinsics(P_cam, Q_cam, width=cw, height=ch, names=names, flags=camera_flags, device="camera")
    else:
        if (camera.width, camera.height) != (cw, ch):
            raise CalibrationError(
                f"the given camera calibration is for {camera.width}x{camera.height} images, the captures are {cw}x{ch}"
            )
        cam_res = _fixed_camera_result(camera, P_cam, Q_cam, names)
    proj_res = calibrate_intrinsics(
        P_both, Q_proj, width=projector_width, height=projector_height, names=names, flags=projector_flags, device="projector"
    )
    if joint is None:
        joint = len(views) >= JOINT_MIN_VIEWS
    flags = cv2.CALIB_FIX_INTRINSIC
    if joint and camera is None:
        flags = cv2.CALIB_USE_INTRINSIC_GUESS | camera_flags | projector_flags
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    Kc, dc = cam_res.intrinsics.K.copy(), cam_res.intrinsics.dist.copy()
    Kp, dp = proj_res.intrinsics.K.copy(), proj_res.intrinsics.dist.copy()
    try:
        rms, Kc, dc, Kp, dp, R, T, _E, _F, _rv, _tv, per_view = cv2.stereoCalibrateExtended(
            [p.astype(np.float32) for p in P_both],
            [q.astype(np.float32).reshape(-1, 1, 2) for q in Q_cam_both],
            [q.astype(np.float32).reshape(-1, 1, 2) for q in Q_proj],
            Kc, dc, Kp, dp,
            (cw, ch),  # OpenCV's imageSize is (W, H); only used to initialise, we pass intrinsics
            None, None,
            flags=flags,
            criteria=crit,
        )
    except cv2.error as e:
        raise CalibrationError(f"the joint camera–projector solve failed ({e.err}); capture more poses tilted in different directions") from e
    cam = Intrinsics(cw, ch, Kc, np.ravel(dc)[: max(5, len(cam_res.intrinsics.dist))])
    proj = Intrinsics(projector_width, projector_height, Kp, np.ravel(dp)[: max(5, len(proj_res.intrinsics.dist))])
    # stereoCalibrate: p_2 = R p_1 + T with device 1 = camera, 2 = projector  ->  p_proj = R p_cam + t.
    procam = ProCam(cam, proj, R, np.ravel(T))
    return ProcamResult(procam, cam_res, proj_res, float(rms), np.asarray(per_view, np.float64).reshape(-1, 2), tuple(views), notes, bool(joint and camera is None))


def _fixed_camera_result(camera: Intrinsics, P, Q, names) -> IntrinsicsResult:
    """An IntrinsicsResult for a camera whose intrinsics are given: per-view errors from solvePnP."""
    from calibration.report import coverage_fraction

    rv, tv, res, per = [], [], [], []
    for p, q in zip(P, Q):
        ok, r, t = cv2.solvePnP(p, q, camera.K, camera.dist)
        proj = cv2.projectPoints(p, r, t, camera.K, camera.dist)[0].reshape(-1, 2)
        rv.append(r.ravel()), tv.append(t.ravel()), res.append(q - proj)
        per.append(float(np.sqrt(np.mean(np.sum((q - proj) ** 2, axis=1)))))
    allr = np.concatenate(res)
    return IntrinsicsResult(
        camera, float(np.sqrt(np.mean(np.sum(allr**2, axis=1)))), np.array(per), {}, np.array(rv), np.array(tv), res, tuple(names),
        coverage=coverage_fraction(Q, width=camera.width, height=camera.height), extra={"given": True},
    )


def calibrate_procam_dirs(
    pose_dirs: Sequence[str | os.PathLike],
    *,
    board: Board,
    projector_width: int,
    projector_height: int,
    camera: Intrinsics | None = None,
    joint: bool | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[CalibrationFile, ProcamResult]:
    """`rig calibrate procam`: read and process every pose directory, solve, and build the calibration file."""
    if len(pose_dirs) < MIN_VIEWS:
        raise CalibrationError(
            f"too few board poses: {len(pose_dirs)} directories (need at least {MIN_VIEWS}, better 8-15); "
            "capture more poses, the board tilted 20-45 deg in different directions"
        )
    views = []
    for d in pose_dirs:
        views.append(load_pose(d, board=board, projector_width=projector_width, projector_height=projector_height))
        if progress:
            progress(f"{Path(d).name}: {len(views[-1].ids)} corners, {int(views[-1].projector_ok.sum())} in the projector")
    res = calibrate_procam(views, board=board, projector_width=projector_width, projector_height=projector_height, camera=camera, joint=joint)
    cal = procam_calibration_file(res, board=board, inputs=[str(d) for d in pose_dirs])
    return cal, res


def procam_calibration_file(res: ProcamResult, *, board: Board, inputs: Sequence[str], **more) -> CalibrationFile:
    """The full calibration file (camera, projector, R, t) with quality and provenance."""
    from calibration.camera import provenance

    return CalibrationFile.from_procam(
        res.procam,
        quality=res.quality(),
        provenance=provenance(
            method="Gray code + local homographies (Moreno & Taubin 2012), OpenCV calibrateCameraExtended + stereoCalibrate",
            inputs=inputs,
            board=board,
            units="translations in the board's unit (square_mm)",
            joint_refinement=bool(res.joint),
            **more,
        ),
    )
