"""`rig calibrate`: the guided session, and `rig calibrate camera` / `rig calibrate procam` from files.

Thin: parse and validate the options, call one library function, print the verdict. Heavy imports
(OpenCV, NumPy, the calibration code) happen inside the commands so `rig --help` stays instant.
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

calibrate_app = typer.Typer(
    help="Calibrate the camera, the projector and their pose (guided session on the configured rig, or from files).",
    no_args_is_help=False,
    invoke_without_command=True,
)


def _board(board: str, cols: int | None, rows: int | None, squares: str | None, square_mm: float, marker_mm: float | None, dictionary: str):
    from calibration.boards import CharucoBoard, Chessboard
    from calibration.errors import ConfigError

    if board == "chessboard":
        if cols is None or rows is None:
            raise ConfigError("--board chessboard needs --cols and --rows (the numbers of INNER corners, e.g. 9 and 6)")
        return Chessboard(cols, rows, square_mm)
    if board == "charuco":
        if squares is None or marker_mm is None:
            raise ConfigError("--board charuco needs --squares WxH (squares, e.g. 5x7) and --marker-mm")
        sx, sy = _pair(squares, "--squares")
        return CharucoBoard(sx, sy, square_mm, marker_mm, dictionary)
    raise ConfigError(f"--board: expected chessboard or charuco, got {board!r}")


def _pair(text: str, option: str) -> tuple[int, int]:
    from calibration.errors import ConfigError

    try:
        a, b = (int(x) for x in text.lower().split("x"))
    except ValueError as e:
        raise ConfigError(f"{option}: expected WIDTHxHEIGHT such as 1024x768, got {text!r}") from e
    if a <= 0 or b <= 0:
        raise ConfigError(f"{option}: expected positive sizes, got {text!r}")
    return a, b


_BOARD = typer.Option("chessboard", "--board", help="chessboard or charuco")
_COLS = typer.Option(None, "--cols", help="chessboard: inner corners per row")
_ROWS = typer.Option(None, "--rows", help="chessboard: inner corners per column")
_SQUARES = typer.Option(None, "--squares", help="charuco: squares as WxH, e.g. 5x7")
_SQUARE_MM = typer.Option(..., "--square-mm", help="side of one square in mm (any unit: translations come out in it)")
_MARKER_MM = typer.Option(None, "--marker-mm", help="charuco: side of one marker in mm")
_DICT = typer.Option("DICT_6X6_250", "--dictionary", help="charuco: OpenCV predefined ArUco dictionary")


@calibrate_app.callback()
def session(
    ctx: typer.Context,
    config: Optional[Path] = typer.Option(None, "--config", help="rig.toml (default: the built-in simulated rig)"),
    out: Optional[Path] = typer.Option(None, "--out", help="calibration file to write"),
    captures: Optional[Path] = typer.Option(None, "--captures", help="folder for the raw captures (default: beside --out)"),
    poses: int = typer.Option(10, "--poses", min=3, max=40, help="simulated rig: number of board poses"),
    recording: Optional[Path] = typer.Option(None, "--recording", help="also write a Rerun recording (.rrd)"),
) -> None:
    """Guided calibration on the configured rig; raw captures are written before they are processed."""
    if ctx.invoked_subcommand is not None:
        return
    from calibration.errors import ConfigError
    from rig.calibrate_session import run_session
    from rig.config import load_config

    if out is None:
        raise ConfigError("rig calibrate: --out is required (the calibration file to write), e.g. --out calibration.json")
    cfg = load_config(config)
    result = run_session(cfg, out=out, captures_dir=captures, n_poses=poses, recording=recording, echo=typer.echo)
    for line in result.verdict:
        typer.echo(line)
    typer.echo(f"wrote {out}")


@calibrate_app.command("camera")
def camera(
    images: List[Path] = typer.Argument(..., help="photographs of the board (8-15, tilted in different directions)"),
    out: Path = typer.Option(..., "--out", help="calibration file to write (camera part only)"),
    board: str = _BOARD,
    cols: Optional[int] = _COLS,
    rows: Optional[int] = _ROWS,
    squares: Optional[str] = _SQUARES,
    square_mm: float = _SQUARE_MM,
    marker_mm: Optional[float] = _MARKER_MM,
    dictionary: str = _DICT,
    reject_outliers: bool = typer.Option(False, "--reject-outliers", help="drop views whose error stands out, and solve again"),
) -> None:
    """Camera intrinsics from photographs of a chessboard or ChArUco board (no rig needed)."""
    from calibration.camera import calibrate_camera_images
    from calibration.file import save_calibration
    from calibration.report import verdict

    b = _board(board, cols, rows, squares, square_mm, marker_mm, dictionary)
    cal, res = calibrate_camera_images(images, board=b, reject_outliers=reject_outliers)
    save_calibration(cal, out)
    K = res.intrinsics
    typer.echo(f"camera {K.width}x{K.height}: fx {K.fx:.2f} fy {K.fy:.2f} cx {K.cx:.2f} cy {K.cy:.2f} (std fx {res.std.get('fx', 0):.2f} px)")
    if res.rejected:
        typer.echo(f"rejected outlier views: {', '.join(res.rejected)}")
    missing = cal.quality.get("board_not_found")
    if missing:
        typer.echo(f"board not found in: {', '.join(missing)}")
    for line in verdict(cal.quality):
        typer.echo(line)
    typer.echo(f"wrote {out}")


@calibrate_app.command("procam")
def procam(
    pose_dirs: List[Path] = typer.Argument(..., help="one folder per board pose, each captured under Gray code"),
    out: Path = typer.Option(..., "--out", help="calibration file to write"),
    projector_size: str = typer.Option(..., "--projector-size", help="projector resolution WxH, e.g. 1024x768"),
    board: str = _BOARD,
    cols: Optional[int] = _COLS,
    rows: Optional[int] = _ROWS,
    squares: Optional[str] = _SQUARES,
    square_mm: float = _SQUARE_MM,
    marker_mm: Optional[float] = _MARKER_MM,
    dictionary: str = _DICT,
    camera: Optional[Path] = typer.Option(None, "--camera", help="fix the camera intrinsics from this calibration file"),
    joint: Optional[bool] = typer.Option(None, "--joint/--fix-intrinsics", help="stereo solve refines the intrinsics too (default: from 8 poses on)"),
) -> None:
    """Camera, projector and their pose from board poses captured under Gray code (ours or OpenCV's layout)."""
    from calibration.file import load_calibration, save_calibration
    from calibration.procam import calibrate_procam_dirs
    from calibration.report import verdict

    b = _board(board, cols, rows, squares, square_mm, marker_mm, dictionary)
    pw, ph = _pair(projector_size, "--projector-size")
    cam = load_calibration(camera).camera.to_intrinsics() if camera is not None else None
    cal, _res = calibrate_procam_dirs(pose_dirs, board=b, projector_width=pw, projector_height=ph, camera=cam, joint=joint, progress=typer.echo)
    save_calibration(cal, out)
    for line in verdict(cal.quality):
        typer.echo(line)
    typer.echo(f"wrote {out}")


def register(app: typer.Typer) -> None:
    """Add `rig calibrate` (session) and its `camera` / `procam` subcommands."""
    app.add_typer(calibrate_app, name="calibrate")
