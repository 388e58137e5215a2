"""The guided calibration session (`rig calibrate`): capture board poses under Gray code, then calibrate.

Orchestration only: devices come from the registry (rig.registry), algorithms from calibration.procam.
Every pose is written to disk as a raw capture directory (docs/recording.md layout: manifest.json,
frames.jsonl, frames/NNNNNN.png; pattern ids index the Gray-code sequence) BEFORE it is processed, so the
calibration can always be recomputed offline with `rig calibrate procam DIR/pose_*`.

On the simulated rig the board moves through a planned set of poses by itself: for each pose a SimWorld
is built whose scene holds only the printed board (a TexturedPlane), and the simulated projector and
camera run the same show -> grab loop as real devices. On a real rig the user moves the board; after
each pose the session says how far the coverage got and where to put the board next.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from calibration.boards import Chessboard
from calibration.errors import CalibrationError, ConfigError
from calibration.file import CalibrationFile, save_calibration
from calibration.graycode import graycode_patterns
from calibration.models import ProCam, look_at, rotation_from_euler_deg
from calibration.procam import ProcamResult, calibrate_procam, load_pose, procam_calibration_file
from calibration.report import GOOD_COVERAGE, GOOD_VIEWS, coverage_fraction, empty_regions, verdict
from rig.config import RigConfig

#: (rx, ry, rz) tilts in degrees of the planned simulated poses, in order; distances vary around the
#: working distance. Tilts of 25-40 deg in both directions about both axes condition the focal lengths
#: and principal points (with 15-30 deg the simulated principal points came out 3 px off).
POSE_TILTS_DEG = (
    (0, 0, 0),
    (35, 0, 7),
    (-35, 0, -7),
    (0, 35, 0),
    (0, -35, 14),
    (25, 25, -14),
    (-25, 25, 14),
    (25, -25, 14),
    (-25, -25, -14),
    (14, 7, 35),
    (-14, -7, -35),
    (39, 14, 0),
    (-14, 39, 7),
    (7, -39, -7),
    (-39, -14, 0),
)


# --- the simulated board ------------------------------------------------------------------------------------------


def board_texture(board: Chessboard, *, mm_per_texel: float, black: int = 25, white: int = 230) -> tuple[np.ndarray, tuple[float, float]]:
    """A printed chessboard: (H, W) uint8 texture and the board-frame (x, y) mm of its top-left corner.

    (cols + 1) x (rows + 1) squares with a white margin of half a square; the board origin is the first
    inner corner (CONVENTIONS.md), so the texture starts 1.5 squares up and left of it.
    """
    s = board.square_mm
    n = int(round(s / mm_per_texel))
    if n < 4:
        raise ValueError(f"mm_per_texel {mm_per_texel} is too coarse for {s} mm squares")
    margin = n // 2
    nx, ny = board.cols + 1, board.rows + 1
    checker = (np.add.outer(np.arange(ny), np.arange(nx)) % 2 == 0)  # the top-left square is black
    tex = np.where(np.kron(checker, np.ones((n, n), bool)), black, white).astype(np.uint8)
    tex = np.pad(tex, margin, constant_values=white)
    origin = -(s + margin * s / n)
    return tex, (origin, origin)


def working_point(procam: ProCam, *, default_mm: float = 800.0) -> np.ndarray:
    """Where the rays through the projector's and the camera's image centres pass closest (projector
    frame, mm); image centres, not principal points, because a projector's lens shift moves its axis
    to the edge of its image."""
    def centre_ray(dev):
        return dev.rays(np.array([[(dev.width - 1) / 2, (dev.height - 1) / 2]]))[0]

    o1, d1 = np.zeros(3), centre_ray(procam.projector)
    o2, d2 = procam.t_proj_cam, procam.R_proj_cam @ centre_ray(procam.camera)
    w = o1 - o2
    a, b, c, d, e = d1 @ d1, d1 @ d2, d2 @ d2, d1 @ w, d2 @ w
    den = a * c - b * b
    if den < 1e-9:
        return np.array([0.0, 0.0, default_mm])
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    p = 0.5 * ((o1 + s * d1) + (o2 + t * d2))
    return p if p[2] > 0 else np.array([0.0, 0.0, default_mm])


def default_board(procam: ProCam, *, fill: float = 0.55) -> Chessboard:
    """A 9x7-corner chessboard whose squares make it span about `fill` of the narrower field of view."""
    z = float(working_point(procam)[2])
    fov = min(procam.projector.width / procam.projector.fx, procam.camera.width / procam.camera.fx,
              procam.projector.height / procam.projector.fy, procam.camera.height / procam.camera.fy) * z
    square = max(1.0, round(fill * fov / 10, 0))
    return Chessboard(9, 7, float(square))


def _corners_inside(procam: ProCam, p_proj: np.ndarray, margin: float) -> bool:
    for dev, pts in ((procam.projector, p_proj), (procam.camera, procam.proj_to_cam(p_proj))):
        if np.any(pts[:, 2] <= 0):
            return False
        q = dev.project(pts)
        mu, mv = margin * dev.width, margin * dev.height
        if not (np.all(np.isfinite(q)) and np.all(q[:, 0] > mu) and np.all(q[:, 0] < dev.width - 1 - mu)
                and np.all(q[:, 1] > mv) and np.all(q[:, 1] < dev.height - 1 - mv)):
            return False
    return True


def plan_board_poses(procam: ProCam, board: Chessboard, *, n_poses: int, seed: int = 0, margin: float = 0.04) -> list[tuple[np.ndarray, np.ndarray]]:
    """Board poses (R_proj_board, t_proj_board) seen whole by the camera and lit whole by the projector.

    Tilts follow POSE_TILTS_DEG about a base orientation facing the devices; position and distance are
    jittered (seeded). A tilt that does not fit is shrunk until it does.
    """
    rng = np.random.default_rng(seed)
    centre = working_point(procam)
    mid = 0.5 * procam.t_proj_cam
    base = look_at(mid, centre)  # board z (into the board) points away from the devices
    centre_board = np.array([(board.cols - 1) / 2, (board.rows - 1) / 2, 0.0]) * board.square_mm
    P = board.object_points_mm
    outline = np.array([[-1, -1, 0], [board.cols, -1, 0], [-1, board.rows, 0], [board.cols, board.rows, 0]]) * board.square_mm
    poses = []
    for k in range(n_poses):
        tilt = np.array(POSE_TILTS_DEG[k % len(POSE_TILTS_DEG)], float)
        for attempt in range(60):
            # after 20 misses: smaller tilts, less jitter, a little farther away
            late = max(0, attempt - 19)
            R = base @ rotation_from_euler_deg(*(tilt * 0.97**late))
            jitter = 0.95**late
            z = centre[2] * (1.0 + 0.01 * late + jitter * rng.uniform(-0.12, 0.12))
            c = centre * z / centre[2] + np.r_[jitter * rng.uniform(-0.05, 0.05, 2) * z, 0.0]
            t = c - R @ centre_board
            pts = np.vstack([P, outline]) @ R.T + t
            if _corners_inside(procam, pts, margin):
                poses.append((R, t))
                break
        else:
            raise CalibrationError(f"cannot place a {board.square_mm} mm board so that both devices see it whole (pose {k})")
    return poses


def _board_plane_class():
    """TexturedPlane whose texture lookup passes OpenCV 5's remap maps of < 32767 rows.

    drivers.sim's TexturedPlane.albedo_at hands cv2.remap (N, 1) maps of up to 2**20 rows, which OpenCV 5
    refuses (SHRT_MAX assertion) as soon as a board covers more than 32767 camera sub-samples; reported
    to the simulator's owner, worked around here by lookups in chunks of 32000.
    """
    import cv2

    from drivers.sim import TexturedPlane

    class BoardPlane(TexturedPlane):
        def albedo_at(self, p: np.ndarray) -> np.ndarray:
            pb = (np.asarray(p, np.float64) - self.t_proj_board) @ self.R_proj_board
            x0, y0 = self.texture_origin_mm
            c = ((pb[:, 0] - x0) / self.mm_per_texel - 0.5).astype(np.float32)
            r = ((pb[:, 1] - y0) / self.mm_per_texel - 0.5).astype(np.float32)
            out = np.zeros(len(pb))
            for lo in range(0, len(pb), 32000):
                hi = lo + 32000
                v = cv2.remap(self.texture, c[lo:hi, None], r[lo:hi, None], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                out[lo:hi] = v.reshape(-1)
            return self.albedo * out

    return BoardPlane


def sim_world_with_board(procam: ProCam, board: Chessboard, pose, *, options, seed: int):
    """A SimWorld whose scene holds only the printed board at `pose` = (R_proj_board, t_proj_board)."""
    from drivers.sim import Scene, SimWorld
    from drivers.sim.presets import SimRig, depth_range

    TexturedPlane = _board_plane_class()

    R, t = pose
    z = float((t + R @ np.array([board.cols, board.rows, 0]) * board.square_mm / 2)[2])
    footprint = z / procam.camera.fx / options.supersample  # mm seen by one camera sub-sample
    mm_per_texel = board.square_mm / min(300, math.ceil(board.square_mm / footprint))
    tex, origin = board_texture(board, mm_per_texel=mm_per_texel)
    scene = Scene([TexturedPlane(R, t, tex, mm_per_texel, origin)])
    rig = SimRig("calibration-board", procam, scene, depth_range(procam, scene), "a chessboard for calibration")
    return SimWorld(rig, options=options, seed=seed)


# --- capture ------------------------------------------------------------------------------------------------------


def capture_pose(projector, camera, patterns: Sequence[np.ndarray], pose_dir: Path, *, settle_s: float, timeout_s: float, header: dict) -> Path:
    """Show every pattern, grab a fresh frame after each, write them as a capture directory; returns it.

    The projector must already hold `patterns` (projector.load). Frames are on disk (fsynced) before
    this returns; nothing is processed here.
    """
    from rig.capture import CaptureWriter

    with CaptureWriter(pose_dir, header=header) as writer:
        for i in range(len(patterns)):
            shown = projector.show(i)
            frame = camera.grab(after_s=shown.host_time_s + settle_s, timeout_s=timeout_s)
            writer.write_frame(frame.image, pattern=i, timestamp_s=frame.timestamp_s, device_time_us=shown.device_time_us)
    projector.stop()
    return pose_dir


@dataclass
class SessionResult:
    """What `run_session` produced: the calibration file, the solve, the pose directories, the verdict."""

    calibration: CalibrationFile
    result: ProcamResult
    pose_dirs: list[Path]
    verdict: list[str] = field(default_factory=list)


def _header(board: Chessboard, width: int, height: int, k: int, **more) -> dict:
    return {
        "pattern": {"kind": "graycode", "order": "opencv", "projector_width": width, "projector_height": height},
        "board": board.describe(),
        "pose_index": k,
        **more,
    }


def _feedback(views, procam_like_sizes) -> tuple[str, list[str]]:
    (cw, ch), (pw, ph) = procam_like_sizes
    cov_c = coverage_fraction([v.q_cam for v in views], width=cw, height=ch)
    cov_p = coverage_fraction([v.q_proj[v.projector_ok] for v in views], width=pw, height=ph)
    empty = empty_regions([v.q_proj[v.projector_ok] for v in views], width=pw, height=ph)
    line = f"{len(views)} poses, coverage camera {100 * cov_c:.0f} %, projector {100 * cov_p:.0f} %"
    return line, (empty if cov_p < GOOD_COVERAGE else [])


def render_pose_images(procam: ProCam, board: Chessboard, pose, *, options, seed: int) -> list[np.ndarray]:
    """The camera images of the board at `pose` under every Gray-code pattern (in memory, no devices)."""
    world = sim_world_with_board(procam, board, pose, options=options, seed=seed)
    return [world.render(p) for p in graycode_patterns(procam.projector.width, procam.projector.height)]


def simulate_poses(
    procam: ProCam, board: Chessboard, *, n_poses: int, captures_dir: Path, options, seed: int = 0, echo: Callable[[str], None] = lambda s: None
) -> list[Path]:
    """Render the board at planned poses under the Gray code with the simulated devices; write each pose."""
    from drivers.sim import SimCamera, SimProjector

    patterns = graycode_patterns(procam.projector.width, procam.projector.height)
    dirs = []
    for k, pose in enumerate(plan_board_poses(procam, board, n_poses=n_poses, seed=seed)):
        world = sim_world_with_board(procam, board, pose, options=options, seed=seed + 1000 * (k + 1))
        with SimProjector(world) as proj, SimCamera(world, source=proj) as cam:
            proj.load(patterns)
            d = capture_pose(proj, cam, patterns, captures_dir / f"pose_{k:02d}", settle_s=0.0, timeout_s=5.0,
                             header=_header(board, procam.projector.width, procam.projector.height, k,
                                            sim_truth_board={"R_proj_board": pose[0].tolist(), "t_proj_board": pose[1].tolist()}))
        dirs.append(d)
        echo(f"captured {d.name}")
    return dirs


def run_session(
    cfg: RigConfig,
    *,
    out: Path,
    captures_dir: Path | None = None,
    n_poses: int = 10,
    board: Chessboard | None = None,
    recording: Path | None = None,
    echo: Callable[[str], None] = print,
    ask: Callable[[str], str] | None = None,
) -> SessionResult:
    """Capture, record, calibrate, write `out`, and return the verdict.

    Simulated rig: `n_poses` planned poses, rendered with the configured noise, ambient and gamma.
    Real rig: the user places the board (`ask` prompts; empty answer = capture, "q" = stop), guided by the
    coverage after each pose. Raw captures go to `captures_dir` (default: OUT's stem + "_captures").
    """
    from rig.registry import render_options, sim_rig_from_config

    captures_dir = captures_dir or out.with_name(out.stem + "_captures")
    if captures_dir.exists() and any(captures_dir.iterdir()):
        raise ConfigError(f"{captures_dir} is not empty; choose another --captures folder (raw captures are never overwritten)")
    captures_dir.mkdir(parents=True, exist_ok=True)
    if cfg.camera.device == "sim" and cfg.projector.port == "sim":
        truth = sim_rig_from_config(cfg).procam
        board = board or default_board(truth)
        pw, ph = truth.projector.width, truth.projector.height
        echo(f"simulated rig: {n_poses} poses of a {board.cols}x{board.rows}-corner chessboard, {board.square_mm:g} mm squares")
        dirs = simulate_poses(truth, board, n_poses=n_poses, captures_dir=captures_dir, options=render_options(cfg), seed=cfg.sim.seed, echo=echo)
    else:
        truth = None
        if board is None:
            raise ConfigError("a real rig needs the board: pass it to run_session (the CLI's --board options)")
        dirs, pw, ph = _guided_real(cfg, board, captures_dir=captures_dir, echo=echo, ask=ask or input)
    views = []
    for d in dirs:
        views.append(load_pose(d, board=board, projector_width=pw, projector_height=ph))
    res = calibrate_procam(views, board=board, projector_width=pw, projector_height=ph)
    cal = procam_calibration_file(res, board=board, inputs=[str(d) for d in dirs], session="rig calibrate", simulated=truth is not None)
    save_calibration(cal, out)
    lines = verdict(cal.quality)
    if truth is not None:
        lines.append(truth_comparison(res.procam, truth))
    if recording is not None:
        log_session(recording, res)
        lines.append(f"recording: {recording}")
    return SessionResult(cal, res, dirs, lines)


def truth_comparison(est: ProCam, truth: ProCam) -> str:
    """One line: how far the estimate is from the simulated truth."""
    import cv2

    dR = cv2.Rodrigues(est.R_proj_cam @ truth.R_proj_cam.T)[0]
    df = max(abs(est.camera.fx / truth.camera.fx - 1), abs(est.projector.fx / truth.projector.fx - 1),
             abs(est.camera.fy / truth.camera.fy - 1), abs(est.projector.fy / truth.projector.fy - 1))
    dt = np.linalg.norm(est.t_proj_cam - truth.t_proj_cam) / truth.baseline_mm
    return (f"against the simulated truth: focal lengths within {100 * df:.3f} %, rotation {np.degrees(np.linalg.norm(dR)):.4f} deg, "
            f"translation {100 * dt:.3f} % of the baseline")


def _guided_real(cfg: RigConfig, board: Chessboard, *, captures_dir: Path, echo, ask) -> tuple[list[Path], int, int]:
    """The user moves the board; each pose is captured, written, then checked for coverage feedback."""
    from rig.registry import open_rig

    dirs: list[Path] = []
    views = []
    with open_rig(cfg) as rig:
        pw, ph = rig.procam.projector.width, rig.procam.projector.height
        patterns = graycode_patterns(pw, ph)
        rig.projector.load(patterns)
        k = 0
        while True:
            hint = "" if not views else " (" + _feedback(views, ((rig.camera.width, rig.camera.height), (pw, ph)))[0] + ")"
            answer = ask(f"place the board for pose {k + 1}{hint}; Enter = capture, q = finish: ").strip().lower()
            if answer == "q":
                break
            d = capture_pose(rig.projector, rig.camera, patterns, captures_dir / f"pose_{k:02d}",
                             settle_s=cfg.camera.settle_ms / 1000, timeout_s=cfg.camera.timeout_ms / 1000,
                             header=_header(board, pw, ph, k))
            try:
                views.append(load_pose(d, board=board, projector_width=pw, projector_height=ph))
                dirs.append(d)
            except CalibrationError as e:
                echo(f"pose {k + 1} not usable (kept on disk): {e}")
            k += 1
            if views:
                line, empty = _feedback(views, ((rig.camera.width, rig.camera.height), (pw, ph)))
                echo(line + (f"; next: put the board in the projector's {', '.join(empty[:2])}" if empty else ""))
                if len(views) >= GOOD_VIEWS and not empty:
                    echo("enough views; capture more or press q")
    return dirs, pw, ph


def log_session(path: Path, res: ProcamResult) -> None:
    """A Rerun recording of the calibration: both frusta, each view's corners and residual vectors."""
    import rerun as rr

    pc = res.procam
    rec = rr.RecordingStream("rig_calibrate")
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    rec.log("world/projector", rr.Pinhole(image_from_camera=pc.projector.K, resolution=[pc.projector.width, pc.projector.height]), static=True)
    rec.log("world/camera", rr.Transform3D(translation=pc.t_proj_cam, mat3x3=pc.R_proj_cam), static=True)
    rec.log("world/camera", rr.Pinhole(image_from_camera=pc.camera.K, resolution=[pc.camera.width, pc.camera.height]), static=True)
    for k, (v, r) in enumerate(zip(res.views, res.camera.residuals_px)):
        rec.set_time("view", sequence=k)
        rec.log("world/camera/corners", rr.Points2D(v.q_cam, radii=2.0))
        rec.log("world/camera/residuals", rr.Arrows2D(origins=v.q_cam, vectors=r * 50.0))
        ok = v.projector_ok
        rec.log("world/projector/corners", rr.Points2D(v.q_proj[ok], radii=2.0))
    rec.save(str(path))
