"""The acquisition loop: show/trigger → acknowledgement → settle → grab → verify → write raw → process → log.

Orchestration only; every device call goes through the protocols in drivers.base. Memory stays constant over any
number of frames (nothing is kept after a frame is logged). Ctrl-C stops cleanly: the frames captured so far stay on
disk and the recording is closed properly.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.errors import DeviceError, RigError
from calibration.file import CalibrationFile, dumps_calibration, write_text_atomic
from rig.config import RigConfig, config_to_toml


@dataclass(frozen=True)
class ScanRequest:
    """What `rig scan` was asked for. Products named with `ply`/`depth` get a _NNNNNN suffix when frames > 1."""

    out: Path
    frames: int = 1
    record: Path | None = None
    ply: Path | None = None
    depth: Path | None = None
    reconstruct: bool = True
    pattern: str = "grid"


@dataclass
class ScanSummary:
    out: Path
    scans_requested: int
    frames_captured: int = 0
    scans_done: int = 0
    points_total: int = 0
    interrupted: bool = False
    error: str | None = None
    record: Path | None = None
    reconstructed: bool = False
    warnings: list[str] = field(default_factory=list)
    calibration_source: str = ""


def _numbered(path: Path | None, index: int, total: int) -> Path | None:
    if path is None or total == 1:
        return path
    return path.with_name(f"{path.stem}_{index:06d}{path.suffix}")


def _black_level(image: np.ndarray) -> float:
    """Brightest grey level in the frame, on an 8-bit scale."""
    peak = float(np.percentile(image[::4, ::4], 99.5))
    return peak / 257.0 if image.dtype == np.uint16 else peak


def grab_verified(camera, shown, *, settle_s: float, timeout_s: float, black_grey: float = 8.0):
    """Grab the first frame exposed after the pattern switch plus the settle time; reject black frames.

    A black frame (lens cap, exposure far too short, projector dark) is grabbed again once, then an error.
    """
    after = shown.host_time_s + settle_s
    for attempt in range(2):
        frame = camera.grab(after_s=after, timeout_s=timeout_s)
        if frame.timestamp_s < after:
            raise DeviceError(
                f"camera returned a frame from {after - frame.timestamp_s:.3f} s before the pattern switch plus settle "
                "time (stale buffer); the driver must drop queued frames"
            )
        if _black_level(frame.image) >= black_grey:
            return frame
        after = frame.timestamp_s
    raise DeviceError(
        "the camera frame is black (99.5th percentile below 8 grey levels): check the lens cap, the exposure "
        "([camera] exposure_ms) and that the projector is on and showing the pattern"
    )


@dataclass(frozen=True)
class ScanMode:
    """What one scan projects and how its frames become a reconstruction.

    patterns: the projector images (pattern ids are their positions); sequence: the pattern ids shown, in
    order, for one scan (one frame each); process(images, request, n) -> dict (points, warnings, ms), or None
    when the scan only captures.
    """

    name: str
    patterns: list
    sequence: list[int]
    process: Callable | None


def scan_mode(cfg: RigConfig, procam, *, pattern: str, reconstruct: bool) -> ScanMode:
    """The grid (one frame per scan) or the Gray-code mode (2·(⌈log2 W⌉ + ⌈log2 H⌉) + 2 frames per scan)."""
    from calibration.errors import ConfigError

    w, h = procam.projector.width, procam.projector.height
    if pattern == "grid":
        problem = cfg.pattern.fits(w, h)
        if problem:
            raise ConfigError(f"[pattern]: {problem}")
        return ScanMode("grid", [cfg.pattern.render(w, h)], [0], _grid_processor(cfg, procam) if reconstruct else None)
    if pattern == "graycode":
        from reconstruction.graycode_depth import graycode_scan_patterns

        patterns = graycode_scan_patterns(w, h)
        return ScanMode(
            "graycode", patterns, list(range(len(patterns))), _graycode_processor(cfg, procam) if reconstruct else None
        )
    raise ConfigError(f"--pattern {pattern!r}: expected 'grid' (single shot) or 'graycode' (dense, static scenes)")


def run_scan(
    cfg: RigConfig,
    request: ScanRequest,
    *,
    on_frame: Callable[[int, dict], None] | None = None,
) -> ScanSummary:
    """Run `request.frames` scans on the configured rig; returns the summary (also on Ctrl-C).

    Each scan shows its mode's pattern sequence, one verified frame per pattern. Device and protocol errors
    propagate after everything captured so far is closed and kept; the summary of what was kept is attached
    to the exception as `e.summary`.
    """
    from rig.recording import open_recording
    from rig.registry import open_rig

    summary = ScanSummary(out=request.out, scans_requested=request.frames, record=request.record)
    with contextlib.ExitStack() as stack:
        capture = None
        transcript = None
        if request.record is not None:
            from rig.capture import CaptureWriter

            capture = CaptureWriter(
                request.record,
                header={
                    "mode": request.pattern,
                    "config": config_to_toml(cfg),
                    "pattern": cfg.pattern.model_dump(mode="json"),
                    "camera": cfg.camera.model_dump(mode="json"),
                },
            )
            stack.callback(lambda: capture.close(complete=summary.error is None and not summary.interrupted,
                                                 summary={"frames": summary.frames_captured,
                                                          "interrupted": summary.interrupted,
                                                          "error": summary.error}))
            transcript = capture.transcript_path
        rig = stack.enter_context(open_rig(cfg, transcript=transcript))
        procam = rig.procam
        summary.calibration_source = rig.calibration_source
        mode = scan_mode(cfg, procam, pattern=request.pattern, reconstruct=request.reconstruct)
        rig.projector.load(mode.patterns)
        devices = {"projector": rig.projector.describe(), "camera": rig.camera.describe()}
        if capture is not None:
            capture.header["devices"] = devices
            capture.header["calibration_source"] = rig.calibration_source
            for k, image in enumerate(mode.patterns):
                capture.write_pattern(k, image)
            write_text_atomic(capture.dir / "calibration.json", dumps_calibration(CalibrationFile.from_procam(procam)))

        summary.reconstructed = mode.process is not None
        single = len(mode.sequence) == 1
        rec = stack.enter_context(
            open_recording(request.out, procam=procam, pattern_image=mode.patterns[0] if single else None,
                           report={"calibration": rig.calibration_source, "devices": devices, "mode": mode.name})
        )
        settle_s = cfg.camera.settle_ms / 1000.0
        timeout_s = cfg.camera.timeout_ms / 1000.0
        frame_no = 0
        try:
            for n in range(request.frames):
                images = []
                for pattern_id in mode.sequence:
                    shown = rig.projector.show(pattern_id)
                    frame = grab_verified(rig.camera, shown, settle_s=settle_s, timeout_s=timeout_s,
                                          black_grey=8.0 if single else 0.0)
                    meta = {"device_time_us": shown.device_time_us, "exposure_ms": cfg.camera.exposure_ms}
                    # Raw data first: on disk (and in the recording) before anything can fail on it.
                    if capture is not None:
                        capture.write_frame(frame.image, pattern=shown.index, timestamp_s=frame.timestamp_s, **meta)
                    rec.log_frame(frame_no, frame.image, timestamp_s=frame.timestamp_s)
                    if not single:
                        rec.log_pattern(mode.patterns[pattern_id], index=pattern_id)
                    summary.frames_captured += 1
                    frame_no += 1
                    images.append(frame.image)
                info: dict = {"scan": n, "frame": frame_no - 1}
                if mode.process is not None:
                    info.update(mode.process(rec, images, n, request))
                    summary.points_total += info.get("points", 0)
                    for w in info.get("warnings", []):
                        summary.warnings.append(f"scan {n}: {w}")
                del images
                summary.scans_done += 1
                if on_frame is not None:
                    on_frame(n, info)
        except KeyboardInterrupt:
            summary.interrupted = True
        except RigError as e:
            summary.error = str(e)
            e.summary = summary  # type: ignore[attr-defined]
            raise
        finally:
            with contextlib.suppress(Exception):
                rig.projector.stop()
    return summary


def save_products(result, *, ply: Path | None, depth: Path | None) -> None:
    """Write a reconstruction's PLY (points + family, i, j, residual per vertex) and depth .npy, atomically."""
    from reconstruction.io import write_depth_npy, write_ply

    if ply is not None:
        lab = result.label
        write_ply(ply, result.points_proj, family=result.family, i=lab[:, 0], j=lab[:, 1], residual=result.residual)
    if depth is not None:
        write_depth_npy(depth, result.depth_cam)


def _grid_processor(cfg: RigConfig, procam) -> Callable:
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    from rig.registry import working_volume

    depth_min_mm, depth_max_mm = working_volume(cfg)
    options = ReconstructOptions(
        labeller=cfg.reconstruction.labeller, depth_min_mm=depth_min_mm, depth_max_mm=depth_max_mm
    )
    return _processor(lambda images: reconstruct(images[0], procam, cfg.pattern, options=options))


def _graycode_processor(cfg: RigConfig, procam) -> Callable:
    from reconstruction.graycode_depth import GrayCodeOptions, reconstruct_graycode

    from rig.registry import working_volume

    depth_min_mm, depth_max_mm = working_volume(cfg)
    options = GrayCodeOptions(depth_min_mm=depth_min_mm, depth_max_mm=depth_max_mm)
    return _processor(lambda images: reconstruct_graycode(images, procam, options=options))


def _processor(solve: Callable) -> Callable:
    """Wrap a reconstruction function: time it, log the result, write the requested products."""
    from rig.log_reconstruction import log_reconstruction

    def run(rec, images: list, n: int, request: ScanRequest) -> dict:
        t0 = time.perf_counter()
        result = solve(images)
        ms = (time.perf_counter() - t0) * 1000.0
        log_reconstruction(rec.stream, result)
        save_products(result, ply=_numbered(request.ply, n, request.frames), depth=_numbered(request.depth, n, request.frames))
        return {"points": int(len(result.points_proj)), "ms": ms, "warnings": list(result.warnings)}

    return run
