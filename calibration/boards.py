"""Calibration boards and their detection in images.

A board is described by a small frozen spec (`Chessboard`, `CharucoBoard`) whose `object_points_mm` are the
inner corners in the board frame (CONVENTIONS.md: origin at the first inner corner, x along the columns,
y along the rows, z = 0 on the board, millimetres). A detection is a `BoardView`: the corner ids found and
their pixel coordinates `q_cam` (N, 2), (u, v), pixel (0, 0) = centre of the top-left pixel.

OpenCV 5 names used here (checked by introspection): cv2.findChessboardCorners + cv2.cornerSubPix (the
classic detector, whose result OpenCV's own calibration test asserts), cv2.findChessboardCornersSB as a
fallback, cv2.aruco.CharucoBoard / cv2.aruco.CharucoDetector for ChArUco boards.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Union

import cv2
import numpy as np

from calibration.errors import CalibrationError


@dataclass(frozen=True)
class Chessboard:
    """A chessboard with `cols` x `rows` INNER corners and squares of `square_mm` millimetres."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise CalibrationError(f"a chessboard needs at least 3x3 inner corners, got {self.cols}x{self.rows}")
        if not self.square_mm > 0:
            raise CalibrationError(f"square size must be positive, got {self.square_mm} mm")

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def object_points_mm(self) -> np.ndarray:
        """(cols*rows, 3) corner positions, row-major (corner id = row * cols + col), board frame, mm."""
        return _corner_grid_mm(self.cols, self.rows, self.square_mm)

    def describe(self) -> dict:
        return {"kind": "chessboard", "cols": self.cols, "rows": self.rows, "square_mm": self.square_mm}


def _corner_grid_mm(cols: int, rows: int, square_mm: float) -> np.ndarray:
    """(cols*rows, 3) inner-corner positions, row-major (id = row * cols + col), board frame (z = 0), mm."""
    col, row = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.column_stack([col.ravel(), row.ravel(), np.zeros(col.size)]) * square_mm


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board of `squares_x` x `squares_y` squares (inner corners: one fewer each way).

    `dictionary` is an OpenCV predefined dictionary name such as "DICT_6X6_250". `legacy` selects the
    pre-4.6 layout for boards with an even number of rows (printed with old OpenCV versions).
    """

    squares_x: int
    squares_y: int
    square_mm: float
    marker_mm: float
    dictionary: str = "DICT_6X6_250"
    legacy: bool = False

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise CalibrationError(f"a ChArUco board needs at least 3x3 squares, got {self.squares_x}x{self.squares_y}")
        if not 0 < self.marker_mm < self.square_mm:
            raise CalibrationError(
                f"marker size ({self.marker_mm} mm) must be positive and smaller than the square ({self.square_mm} mm)"
            )
        if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r} (use a name such as DICT_6X6_250)")

    @property
    def cols(self) -> int:
        return self.squares_x - 1

    @property
    def rows(self) -> int:
        return self.squares_y - 1

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def object_points_mm(self) -> np.ndarray:
        """(cols*rows, 3) ChArUco corner positions (corner id order), board frame, mm."""
        return _corner_grid_mm(self.cols, self.rows, self.square_mm)

    def opencv_board(self) -> "cv2.aruco.CharucoBoard":
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        # OpenCV takes (squaresX, squaresY) = (columns, rows) of squares.
        b = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm, self.marker_mm, d)
        b.setLegacyPattern(self.legacy)
        return b

    def describe(self) -> dict:
        return {
            "kind": "charuco",
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "square_mm": self.square_mm,
            "marker_mm": self.marker_mm,
            "dictionary": self.dictionary,
        }


Board = Union[Chessboard, CharucoBoard]


@dataclass(frozen=True, eq=False)
class BoardView:
    """The corners of one board found in one image.

    ids: (N,) int corner ids (index into the board's object_points_mm). q_cam: (N, 2) float64 pixels.
    width, height: the image size. source: where the image came from (file name), for messages.
    markers: ChArUco only, {marker id: (4, 2) corner pixels} as detected (before interpolation).
    """

    ids: np.ndarray
    q_cam: np.ndarray
    width: int
    height: int
    source: str = ""
    markers: dict = field(default_factory=dict)

    def object_points_mm(self, board: Board) -> np.ndarray:
        return board.object_points_mm[self.ids]


def as_grey(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3) uint8/uint16 -> (H, W) uint8 (uint16 scaled by its maximum possible value)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.shape[2] == 3 else img[..., 0]
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def _subpix_half_window(q: np.ndarray, cols: int) -> int:
    """Half-size of cornerSubPix's window from the corner spacing: about a sixth of the smallest square
    side, clamped to 3..15 px, so the window never reaches the neighbouring corners (a 23x23 window on
    34-px squares is what makes OpenCV's left02.jpg an "outlier", docs/decisions/0060-…)."""
    g = q.reshape(-1, cols, 2)
    d = np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=2).ravel(), np.linalg.norm(np.diff(g, axis=0), axis=2).ravel()])
    return int(np.clip(round(0.15 * float(np.median(d))), 3, 15))


def detect_chessboard(
    image: np.ndarray, *, board: Chessboard, subpix_half_window_px: int | None = None, source: str = ""
) -> BoardView | None:
    """Find all inner corners of `board` in `image`, refined to sub-pixel accuracy; None if not found.

    The classic detector (findChessboardCorners + cornerSubPix) is tried first; the sector-based
    findChessboardCornersSB is the fallback for blurred or low-contrast images.
    `subpix_half_window_px`: cornerSubPix's half window; None chooses it from the corner spacing.
    """
    grey = as_grey(image)
    h, w = grey.shape
    pattern = (board.cols, board.rows)  # OpenCV's patternSize is (columns, rows) of inner corners
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(grey, pattern, flags=flags)
    if found:
        q = corners.reshape(-1, 2).astype(np.float32)
        win = subpix_half_window_px or _subpix_half_window(q.astype(np.float64), board.cols)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        q = cv2.cornerSubPix(grey, q.reshape(-1, 1, 2), (win, win), (-1, -1), crit).reshape(-1, 2)
    else:
        found, corners = cv2.findChessboardCornersSB(grey, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        if not found:
            return None
        q = corners.reshape(-1, 2)
    return BoardView(np.arange(board.n_corners), q.astype(np.float64), w, h, source)


def detect_charuco(image: np.ndarray, *, board: CharucoBoard, min_corners: int = 6, source: str = "") -> BoardView | None:
    """Find the ChArUco corners visible in `image` (a partial board is fine); None if fewer than `min_corners`."""
    grey = as_grey(image)
    h, w = grey.shape
    detector = cv2.aruco.CharucoDetector(board.opencv_board())
    corners, ids, marker_corners, marker_ids = detector.detectBoard(grey)
    markers = {}
    if marker_ids is not None:
        markers = {int(i): np.asarray(c, np.float64).reshape(4, 2) for i, c in zip(np.ravel(marker_ids), marker_corners)}
    if ids is None or len(ids) < min_corners:
        return None
    return BoardView(np.ravel(ids).astype(np.int64), corners.reshape(-1, 2).astype(np.float64), w, h, source, markers)


def detect_board(image: np.ndarray, *, board: Board, source: str = "") -> BoardView | None:
    """Dispatch on the board kind; see detect_chessboard / detect_charuco."""
    if isinstance(board, CharucoBoard):
        return detect_charuco(image, board=board, source=source)
    return detect_chessboard(image, board=board, source=source)


def read_image(path) -> np.ndarray:
    """Read an image file as stored (grey stays grey, 16-bit stays 16-bit); CalibrationError if unreadable."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CalibrationError(f"{path}: cannot read this image (missing, or not a PNG/JPEG/TIFF)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    return img
