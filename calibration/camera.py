"""Camera intrinsics from photographs of a board: detection + calibrate_intrinsics + the calibration file.

`calibrate_camera_images` is what `rig calibrate camera` calls; `camera_calibration_file` builds the
camera-only calibration file (docs/formats.md) with quality and provenance filled.
"""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from calibration.boards import Board, BoardView, detect_board, read_image
from calibration.errors import CalibrationError
from calibration.file import FORMAT_VERSION, CalibrationFile, DeviceCalibration
from calibration.intrinsics import IntrinsicsResult, board_view_arrays, calibrate_intrinsics, check_same_size
from calibration.report import empty_regions


def detect_views(images: Sequence[np.ndarray], *, board: Board, names: Sequence[str]) -> tuple[list[BoardView], list[str]]:
    """Detect the board in every image. Returns (views found, names of images without a board).

    CalibrationError if the images differ in size.
    """
    check_same_size([(im.shape[1], im.shape[0]) for im in images], names)
    found, missing = [], []
    for im, n in zip(images, names):
        v = detect_board(im, board=board, source=n)
        (found if v is not None else missing).append(v if v is not None else n)
    return found, missing


def calibrate_camera_images(
    paths: Sequence[str | os.PathLike], *, board: Board, reject_outliers: bool = False, flags: int = 0
) -> tuple[CalibrationFile, IntrinsicsResult]:
    """Camera-only calibration from image files. CalibrationError when the board is found in too few."""
    if not paths:
        raise CalibrationError("no images given: pass the photographs of the board (8-15, tilted in different directions)")
    names = [Path(p).name for p in paths]
    images = [read_image(p) for p in paths]
    views, missing = detect_views(images, board=board, names=names)
    if len(views) < 3:
        raise CalibrationError(
            f"the {describe_board(board)} was found in only {len(views)} of {len(paths)} images"
            + (f" (not in {', '.join(missing[:5])}{'…' if len(missing) > 5 else ''})" if missing else "")
            + ": check --cols/--rows (INNER corners) or --squares, and capture images with the whole board sharp and visible"
        )
    P, Q, n = board_view_arrays(views, board)
    w, h = views[0].width, views[0].height
    res = calibrate_intrinsics(P, Q, width=w, height=h, names=n, flags=flags, reject_outliers=reject_outliers)
    extra = {"board_not_found": missing} if missing else {}
    cal = camera_calibration_file(res, board=board, inputs=[str(p) for p in paths], extra_quality=extra, empty=empty_regions(Q, width=w, height=h))
    return cal, res


def describe_board(board: Board) -> str:
    d = board.describe()
    if d["kind"] == "chessboard":
        return f"{d['cols']}x{d['rows']}-corner chessboard"
    return f"{d['squares_x']}x{d['squares_y']}-square ChArUco board ({d['dictionary']})"


def provenance(*, method: str, inputs: Sequence[str], board: Board, **more) -> dict:
    """Where a calibration came from: tool, versions, inputs, board, time."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        rig_version = version("rig-scanner")
    except PackageNotFoundError:
        rig_version = "unknown"
    return {
        "tool": "rig calibrate",
        "method": method,
        "rig_version": rig_version,
        "opencv_version": cv2.__version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "board": board.describe(),
        "inputs": list(inputs),
        **more,
    }


def camera_calibration_file(
    res: IntrinsicsResult, *, board: Board, inputs: Sequence[str], extra_quality: dict | None = None, empty: list | None = None
) -> CalibrationFile:
    """The camera-only calibration file for one intrinsics result."""
    q = res.quality()
    if empty is not None:
        q["empty_regions"] = empty
    return CalibrationFile(
        format_version=FORMAT_VERSION,
        camera=DeviceCalibration.from_intrinsics(res.intrinsics),
        quality={"camera": q, **(extra_quality or {})},
        provenance=provenance(method="camera intrinsics (OpenCV calibrateCameraExtended)", inputs=inputs, board=board),
    )
